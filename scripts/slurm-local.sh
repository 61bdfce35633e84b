#!/usr/bin/env bash
# A single-node Slurm cluster on this machine, for testing `neurofluid-train sweep --slurm`
# against the real scheduler (no mock): munged, slurmctld and slurmd with a minimal slurm.conf,
# every file in one folder ($NEUROFLUID_SLURM_DIR, default /tmp/neurofluid-slurm). Needs root
# (the daemons, and `apt-get install slurm-wlm munge` when they are missing: Debian 12 ships
# Slurm 22.05). No cgroups, no accounting: process tracking by /proc, one partition `debug`.
#
#   scripts/slurm-local.sh start     # install if needed, write slurm.conf, start the daemons
#   eval "$(scripts/slurm-local.sh env)"   # SLURM_CONF for sbatch, squeue, scontrol
#   NEUROFLUID_SLURM=1 cargo test -p neurofluid-train --test train_tests slurm_sweep:: -- --nocapture
#   scripts/slurm-local.sh stop      # stop the daemons this script started (by their pids)
set -euo pipefail

DIR=${NEUROFLUID_SLURM_DIR:-/tmp/neurofluid-slurm}
CONF=$DIR/slurm.conf
CPUS=${NEUROFLUID_SLURM_CPUS:-$(nproc)}

say() { printf 'slurm-local: %s\n' "$*" >&2; }

install_if_missing() {
    if command -v slurmctld >/dev/null && command -v slurmd >/dev/null \
        && command -v sbatch >/dev/null && command -v munged >/dev/null; then
        return
    fi
    say "installing slurm-wlm and munge"
    DEBIAN_FRONTEND=noninteractive apt-get install -y slurm-wlm munge >&2 \
        || { apt-get update >&2 && DEBIAN_FRONTEND=noninteractive apt-get install -y slurm-wlm munge >&2; }
}

write_conf() {
    mkdir -p "$DIR/state" "$DIR/spool" "$DIR/munge"
    local mem_mb
    mem_mb=$(awk '/MemTotal/ { printf "%d", $2 / 1024 * 0.9 }' /proc/meminfo)
    cat >"$CONF" <<EOF
# Written by scripts/slurm-local.sh: one node, this machine, no cgroups, no accounting.
ClusterName=neurofluid-local
SlurmctldHost=localhost
SlurmUser=root
SlurmdUser=root
AuthType=auth/munge
CredType=cred/munge
StateSaveLocation=$DIR/state
SlurmdSpoolDir=$DIR/spool
SlurmctldPidFile=$DIR/slurmctld.pid
SlurmdPidFile=$DIR/slurmd.pid
SlurmctldLogFile=$DIR/slurmctld.log
SlurmdLogFile=$DIR/slurmd.log
SlurmctldPort=${NEUROFLUID_SLURMCTLD_PORT:-6817}
SlurmdPort=${NEUROFLUID_SLURMD_PORT:-6818}
ProctrackType=proctrack/linuxproc
TaskPlugin=task/none
JobAcctGatherType=jobacct_gather/none
AccountingStorageType=accounting_storage/none
JobCompType=jobcomp/none
SchedulerType=sched/backfill
SelectType=select/cons_tres
SelectTypeParameters=CR_CPU
MpiDefault=none
ReturnToService=2
JobRequeue=1
KillWait=30
SlurmdTimeout=30
InactiveLimit=0
MinJobAge=3600
NodeName=localhost NodeAddr=127.0.0.1 CPUs=$CPUS RealMemory=$mem_mb State=UNKNOWN
PartitionName=debug Nodes=localhost Default=YES MaxTime=INFINITE State=UP
EOF
}

start_munge() {
    if munge -n </dev/null 2>/dev/null | unmunge >/dev/null 2>&1; then
        return
    fi
    id munge >/dev/null 2>&1 || useradd --system --no-create-home munge
    [ -s /etc/munge/munge.key ] || { mkdir -p /etc/munge && mungekey --create --keyfile=/etc/munge/munge.key; }
    chown munge:munge /etc/munge /etc/munge/munge.key
    chmod 700 /etc/munge
    chmod 400 /etc/munge/munge.key
    mkdir -p /run/munge /var/lib/munge /var/log/munge
    chown munge:munge /run/munge /var/lib/munge /var/log/munge
    chmod 755 /run/munge
    runuser -u munge -- /usr/sbin/munged
    cp /run/munge/munged.pid "$DIR/munged.pid"
    say "munged started (pid $(cat "$DIR/munged.pid"))"
}

alive() { [ -s "$1" ] && kill -0 "$(cat "$1")" 2>/dev/null; }

start() {
    install_if_missing
    write_conf
    start_munge
    alive "$DIR/slurmctld.pid" || slurmctld -f "$CONF"
    alive "$DIR/slurmd.pid" || slurmd -f "$CONF" -N localhost
    export SLURM_CONF=$CONF
    for _ in $(seq 60); do
        if sinfo -h -o '%T' 2>/dev/null | grep -qE '^(idle|mixed|allocated)'; then
            say "up: $(sinfo -h -o '%P %D %T %c CPUs')"
            env_line
            return
        fi
        sleep 1
    done
    say "the node did not come up; see $DIR/slurmctld.log and $DIR/slurmd.log"
    exit 1
}

stop_pid_file() {
    local file=$1
    if alive "$file"; then
        local pid
        pid=$(cat "$file")
        kill "$pid"
        for _ in $(seq 30); do kill -0 "$pid" 2>/dev/null || break; sleep 1; done
        say "stopped $(basename "$file" .pid) (pid $pid)"
    fi
    rm -f "$file"
}

stop() {
    stop_pid_file "$DIR/slurmd.pid"
    stop_pid_file "$DIR/slurmctld.pid"
    stop_pid_file "$DIR/munged.pid"
}

env_line() { echo "export SLURM_CONF=$CONF"; }

case "${1:-}" in
    start) start ;;
    stop) stop ;;
    env) env_line ;;
    *)
        echo "usage: $0 start|stop|env" >&2
        exit 2
        ;;
esac
