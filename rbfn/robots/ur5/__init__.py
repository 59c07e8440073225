"""Universal Robots UR5 (CB3): `ur5.urdf`, kinematics and inertials only.

Numbers (the URDF's header cites each): kinematics from Universal Robots' published DH
parameters (UR support article "DH parameters for calculations of kinematics and dynamics", UR5
CB3 manual); masses and centres of mass from the same article; inertias of uniform cylinders as
ROS-Industrial's ur_description approximates them; frame names as ur_description's. No closed
forms: the URDF forms serve it. Preset values: conf/robot/ur5.yaml.
"""
