#!/usr/bin/env bash
# A one-node SLURM cluster on localhost, to try `hydra/launcher=slurm` (and preemption) without a
# real cluster. Everything (config, munge key, state, logs) lives in DIR; nothing in /etc is used.
#
#   bash examples/slurm_local_cluster.sh start DIR   # prints the SLURM_CONF to export
#   export SLURM_CONF=DIR/slurm.conf
#   python train.py -m hydra/launcher=slurm hydra.launcher.partition=local ...
#   bash examples/slurm_local_cluster.sh stop DIR    # cancels its jobs, stops its daemons
#
# Needs slurmctld, slurmd, the SLURM client commands and munged (Debian:
# apt-get install slurmctld slurmd slurm-client munge), run as root (slurmd starts the jobs).
# The node has CPUS cores (default 2) and memory is not a consumable, so jobs asking up to
# three quarters of the machine's memory fit. No accounting: `sacct` fails, and submitit logs
# "Bypassing sacct error" while it waits for the jobs' results, which is harmless.
# A requeued job (`scontrol requeue JOBID`) waits about 2 minutes before it starts again, as
# on any SLURM; `scontrol update JobId=JOBID StartTime=now` starts it at once.
set -euo pipefail

usage() { echo "usage: $0 start|stop DIR" >&2; exit 2; }
[ $# -eq 2 ] || usage
cmd=$1
dir=$(mkdir -p "$2" && cd "$2" && pwd)
conf=$dir/slurm.conf
partition=local

free_port() { python3 -c 'import socket; s = socket.socket(); s.bind(("127.0.0.1", 0)); print(s.getsockname()[1])'; }

alive() { [ -f "$1" ] && kill -0 "$(cat "$1")" 2>/dev/null; }

start() {
    for tool in slurmctld slurmd munged sinfo sbatch scontrol; do
        command -v "$tool" >/dev/null || { echo "$tool not found: install SLURM and munge" \
            "(Debian: apt-get install slurmctld slurmd slurm-client munge)" >&2; exit 1; }
    done
    if alive "$dir/slurmctld.pid" || alive "$dir/slurmd.pid"; then
        echo "a cluster is already running in $dir (stop it first: $0 stop $dir)" >&2; exit 1
    fi
    # munged wants its socket directory (and the path to it) searchable by everyone and its key private.
    chmod 755 "$dir"
    mkdir -p "$dir/munge" "$dir/munge-key" "$dir/state" "$dir/spool" "$dir/log"
    chmod 755 "$dir/munge"
    chmod 700 "$dir/munge-key"
    if [ ! -s "$dir/munge-key/munge.key" ]; then
        dd if=/dev/urandom of="$dir/munge-key/munge.key" bs=1024 count=1 status=none
    fi
    chmod 400 "$dir/munge-key/munge.key"

    local user cpus mem_mb
    user=$(id -un)
    cpus=${CPUS:-2}
    mem_mb=$(awk '/^MemTotal:/ { printf "%d", $2 / 1024 * 3 / 4 }' /proc/meminfo)
    cat > "$conf" <<EOF
# One-node cluster on localhost, written by examples/slurm_local_cluster.sh.
ClusterName=acorbfn
SlurmctldHost=localhost
SlurmctldPort=$(free_port)
SlurmdPort=$(free_port)
SlurmUser=$user
SlurmdUser=$user
AuthType=auth/munge
CredType=cred/munge
AuthInfo=socket=$dir/munge/munge.sock
StateSaveLocation=$dir/state
SlurmdSpoolDir=$dir/spool
SlurmctldPidFile=$dir/slurmctld.pid
SlurmdPidFile=$dir/slurmd.pid
SlurmctldLogFile=$dir/log/slurmctld.log
SlurmdLogFile=$dir/log/slurmd.log
SlurmctldDebug=info
SlurmdDebug=info
MailProg=/bin/true
ProctrackType=proctrack/linuxproc
TaskPlugin=task/none
JobAcctGatherType=jobacct_gather/none
AccountingStorageType=accounting_storage/none
JobCompType=jobcomp/none
MpiDefault=none
SwitchType=switch/none
SchedulerType=sched/backfill
SelectType=select/cons_tres
SelectTypeParameters=CR_CPU
SlurmdParameters=config_overrides
ReturnToService=2
KillWait=2
MinJobAge=600
NodeName=localhost NodeAddr=127.0.0.1 CPUs=$cpus RealMemory=$mem_mb State=UNKNOWN
PartitionName=$partition Nodes=localhost Default=YES MaxTime=INFINITE State=UP
EOF

    munged --key-file="$dir/munge-key/munge.key" --socket="$dir/munge/munge.sock" \
        --pid-file="$dir/munge/munged.pid" --log-file="$dir/log/munged.log" --seed-file="$dir/munge/munged.seed"
    SLURM_CONF=$conf slurmctld -i
    SLURM_CONF=$conf slurmd -N localhost

    local state=""
    for _ in $(seq 1 120); do
        state=$(SLURM_CONF=$conf sinfo -h -n localhost -o %T 2>/dev/null || true)
        [ "$state" = idle ] && break
        sleep 0.5
    done
    if [ "$state" != idle ]; then
        echo "the node did not become idle (state: '${state:-none}'); logs in $dir/log" >&2; exit 1
    fi
    echo "SLURM cluster running in $dir: partition '$partition', $cpus CPUs on localhost"
    echo "export SLURM_CONF=$conf"
}

stop() {
    if [ -f "$conf" ] && alive "$dir/slurmctld.pid"; then
        local jobs
        jobs=$(SLURM_CONF=$conf squeue -h -o %A 2>/dev/null || true)
        if [ -n "$jobs" ]; then
            # shellcheck disable=SC2086
            SLURM_CONF=$conf scancel $jobs || true
            for _ in $(seq 1 40); do
                [ -z "$(SLURM_CONF=$conf squeue -h -o %A 2>/dev/null || true)" ] && break
                sleep 0.5
            done
        fi
    fi
    local pidfile pid
    for pidfile in "$dir/slurmd.pid" "$dir/slurmctld.pid" "$dir/munge/munged.pid"; do
        alive "$pidfile" || continue
        pid=$(cat "$pidfile")
        kill "$pid" 2>/dev/null || true
        for _ in $(seq 1 20); do kill -0 "$pid" 2>/dev/null || break; sleep 0.25; done
        kill -0 "$pid" 2>/dev/null && kill -9 "$pid" 2>/dev/null || true
    done
    # Job steps this cluster's slurmd left behind carry its SLURM_CONF in their environment.
    for pid in $(pgrep -x slurmstepd || true); do
        if tr '\0' '\n' < "/proc/$pid/environ" 2>/dev/null | grep -qxF "SLURM_CONF=$conf"; then
            kill -9 "$pid" 2>/dev/null || true
        fi
    done
    echo "SLURM cluster in $dir stopped"
}

case $cmd in
    start) start ;;
    stop) stop ;;
    *) usage ;;
esac
