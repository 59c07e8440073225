"""Franka Emika Panda: `panda.urdf`, kinematics and inertials only (no fingers).

Numbers (the URDF's header cites each): kinematics and joint limits from Franka's Control
Interface documentation (modified DH parameters, limits table); link inertials from Gaz et al.,
"Dynamic Identification of the Franka Emika Panda Robot With Retrieval of Feasible Parameters
Using Penalty-Based Optimization", IEEE RA-L 4(4), 2019; link 0 and hand inertials and the names
from franka_description. No closed forms: the URDF forms serve it. Preset values:
conf/robot/panda.yaml (joint 3's value an input of the IK there, robot.redundancy: the arm is
redundant for a 6-D pose).
"""
