#!/usr/bin/env bash
# A single-node Slurm cluster on this machine, to prove the workflow's Slurm profile (profiles/slurm/) against a
# real scheduler: a controller (slurmctld), a compute node (slurmd) and the accounting daemon (slurmdbd) on a
# private MariaDB, since the Snakemake Slurm executor plugin follows its jobs through `sacct`.
#
#   tools/local_slurm.sh up       # configure and start everything; prints `export SLURM_CONF=...`
#   tools/local_slurm.sh down     # stop what `up` started and remove its state
#   tools/local_slurm.sh status   # exit 0 if the controller answers and the node is idle or busy
#
# Needs Debian's (or Ubuntu's) slurm-wlm, slurmdbd, munge and mariadb-server packages
# (`apt-get install slurm-wlm slurmdbd munge mariadb-server`) and root, as the daemons run as root here.
# Everything lives under $LOCAL_SLURM_DIR (default /tmp/local-slurm): its own slurm.conf, spool and state
# folders, logs, and a MariaDB data directory listening on 127.0.0.1 only. Clients find the config through
# SLURM_CONF, but inside a job the executor plugin's jobstep clears every SLURM_* variable before it calls
# srun, which then reads the default path: so /etc/slurm/slurm.conf is made a link to this one where no such
# file exists (`up` refuses to replace another), and `down` removes the link. The node declares the machine's cores and most of its memory; with
# LOCAL_SLURM_CPUS / LOCAL_SLURM_MEM_MB it declares more (`SlurmdParameters=config_overrides`), so that jobs
# asking for a real cluster's sizes are scheduled on a small machine too: a test cluster, not a production one.
set -euo pipefail

STATE=${LOCAL_SLURM_DIR:-/tmp/local-slurm}
CTLD_PORT=${LOCAL_SLURM_PORT:-6817}        # slurmctld; slurmd takes the next port, slurmdbd the one after
DB_PORT=${LOCAL_SLURM_DB_PORT:-3307}       # MariaDB, on 127.0.0.1: not the system's default 3306
HOST=$(hostname -s)
CLUSTER=localcluster

die() { echo "error: tools/local_slurm.sh: $*" >&2; exit 1; }

need_tools() {
    local tool
    for tool in slurmctld slurmd slurmdbd sacctmgr munged mariadbd mariadb-install-db; do
        command -v "$tool" >/dev/null || die "$tool not found: apt-get install slurm-wlm slurmdbd munge mariadb-server"
    done
    [ "$(id -u)" = 0 ] || die "run as root (the daemons of this test cluster run as root)"
}

# Waits up to $1 seconds for the command after it to succeed.
wait_for() {
    local seconds=$1; shift
    for _ in $(seq "$((seconds * 2))"); do
        "$@" >/dev/null 2>&1 && return 0
        sleep 0.5
    done
    return 1
}

SYSTEM_CONF=/etc/slurm/slurm.conf

link_system_conf() {
    if [ -L "$SYSTEM_CONF" ] && [ "$(readlink "$SYSTEM_CONF")" = "$STATE/slurm.conf" ]; then return 0; fi
    [ -e "$SYSTEM_CONF" ] && die "$SYSTEM_CONF exists: this machine has a Slurm configuration; not replacing it"
    mkdir -p "$(dirname "$SYSTEM_CONF")" && ln -s "$STATE/slurm.conf" "$SYSTEM_CONF"
}

write_configs() {
    local cpus mem
    cpus=${LOCAL_SLURM_CPUS:-$(nproc)}
    # Most of the memory: the daemons and the submitting Snakemake need some too.
    mem=${LOCAL_SLURM_MEM_MB:-$(awk '/MemTotal/ {print int($2 / 1024 * 0.8)}' /proc/meminfo)}
    mkdir -p "$STATE"/{ctld,spool,log,run}
    cat > "$STATE/slurm.conf" <<EOF
ClusterName=$CLUSTER
SlurmctldHost=$HOST
SlurmctldPort=$CTLD_PORT
SlurmdPort=$((CTLD_PORT + 1))
SlurmUser=root
AuthType=auth/munge
StateSaveLocation=$STATE/ctld
SlurmdSpoolDir=$STATE/spool
SlurmctldPidFile=$STATE/run/slurmctld.pid
SlurmdPidFile=$STATE/run/slurmd.pid
SlurmctldLogFile=$STATE/log/slurmctld.log
SlurmdLogFile=$STATE/log/slurmd.log
# No cgroups: this may run in a container that does not delegate them.
ProctrackType=proctrack/linuxproc
TaskPlugin=task/none
JobAcctGatherType=jobacct_gather/linux
AccountingStorageType=accounting_storage/slurmdbd
AccountingStorageHost=localhost
AccountingStoragePort=$((CTLD_PORT + 2))
JobCompType=jobcomp/none
# The executor plugin names each job's rule in its comment: kept in the accounting, so sacct shows it.
AccountingStoreFlags=job_comment
SelectType=select/cons_tres
SelectTypeParameters=CR_Core_Memory
SlurmdParameters=config_overrides
ReturnToService=2
# Quick turnaround for a test: a finished job leaves the controller's memory after a minute (sacct still has it).
MinJobAge=60
SchedulerParameters=defer_batch
NodeName=$HOST CPUs=$cpus RealMemory=$mem State=UNKNOWN
PartitionName=local Nodes=ALL Default=YES MaxTime=INFINITE State=UP
EOF
    cat > "$STATE/slurmdbd.conf" <<EOF
AuthType=auth/munge
DbdHost=localhost
DbdPort=$((CTLD_PORT + 2))
SlurmUser=root
PidFile=$STATE/run/slurmdbd.pid
LogFile=$STATE/log/slurmdbd.log
StorageType=accounting_storage/mysql
StorageHost=127.0.0.1
StoragePort=$DB_PORT
StorageUser=slurm
StoragePass=slurm
StorageLoc=slurm_acct_db
EOF
    chmod 600 "$STATE/slurmdbd.conf"    # slurmdbd refuses a config others can read (it holds the password)
}

start_munge() {
    # The system's munge key (the package makes one); one munged serves every Slurm on the machine.
    if ! munge -n </dev/null >/dev/null 2>&1; then
        mkdir -p /run/munge && chown munge:munge /run/munge
        runuser -u munge -- munged || die "munged did not start"
        wait_for 10 munge -n || die "munge does not answer"
        touch "$STATE/run/munged.ours"     # `down` stops it; a munged that was running already stays
    fi
}

start_mariadb() {
    if [ ! -d "$STATE/mysql/mysql" ]; then
        mkdir -p "$STATE/mysql" && chown mysql:mysql "$STATE/mysql"
        mariadb-install-db --user=mysql --datadir="$STATE/mysql" --auth-root-authentication-method=socket \
            >"$STATE/log/mariadb-install.log" 2>&1 || die "mariadb-install-db failed: $STATE/log/mariadb-install.log"
    fi
    mariadbd --user=mysql --datadir="$STATE/mysql" --bind-address=127.0.0.1 --port="$DB_PORT" \
        --socket="$STATE/mysql/mysql.sock" --pid-file="$STATE/mysql/mariadb.pid" \
        >"$STATE/log/mariadb.log" 2>&1 &
    wait_for 30 mariadb --socket="$STATE/mysql/mysql.sock" -e "select 1" || die "MariaDB did not start: $STATE/log/mariadb.log"
    mariadb --socket="$STATE/mysql/mysql.sock" <<'EOF'
CREATE DATABASE IF NOT EXISTS slurm_acct_db;
CREATE USER IF NOT EXISTS 'slurm'@'127.0.0.1' IDENTIFIED BY 'slurm';
CREATE USER IF NOT EXISTS 'slurm'@'localhost' IDENTIFIED BY 'slurm';
GRANT ALL ON slurm_acct_db.* TO 'slurm'@'127.0.0.1';
GRANT ALL ON slurm_acct_db.* TO 'slurm'@'localhost';
EOF
}

up() {
    need_tools
    status >/dev/null 2>&1 && { echo "export SLURM_CONF=$STATE/slurm.conf"; return 0; }
    write_configs
    link_system_conf
    export SLURM_CONF=$STATE/slurm.conf
    start_munge
    start_mariadb
    slurmdbd || die "slurmdbd did not start: $STATE/log/slurmdbd.log"
    wait_for 30 sacctmgr -n list cluster || die "slurmdbd does not answer: $STATE/log/slurmdbd.log"
    sacctmgr -i add cluster "$CLUSTER" >/dev/null 2>&1 || true      # already there on a second `up`
    slurmctld || die "slurmctld did not start: $STATE/log/slurmctld.log"
    wait_for 30 scontrol ping || die "slurmctld does not answer: $STATE/log/slurmctld.log"
    slurmd || die "slurmd did not start: $STATE/log/slurmd.log"
    wait_for 60 node_ready || die "the node did not come up: $STATE/log/slurmd.log"
    echo "export SLURM_CONF=$STATE/slurm.conf"
}

node_ready() {
    sinfo -h -N -o %t | grep -qE '^(idle|mix|alloc)'
}

status() {
    [ -f "$STATE/slurm.conf" ] || return 1
    export SLURM_CONF=$STATE/slurm.conf
    scontrol ping >/dev/null 2>&1 && node_ready && sinfo -N -l
}

stop_pidfile() {
    local file=$1 pid
    [ -f "$file" ] || return 0
    pid=$(cat "$file")
    kill "$pid" 2>/dev/null || return 0
    for _ in $(seq 40); do kill -0 "$pid" 2>/dev/null || return 0; sleep 0.25; done
    kill -9 "$pid" 2>/dev/null || true
}

down() {
    [ -d "$STATE" ] || return 0
    export SLURM_CONF=$STATE/slurm.conf
    scancel --user="$(id -un)" >/dev/null 2>&1 || true
    local daemon
    for daemon in slurmd slurmctld slurmdbd; do
        stop_pidfile "$STATE/run/$daemon.pid"
    done
    stop_pidfile "$STATE/mysql/mariadb.pid"      # in its data folder: MariaDB runs as mysql
    [ -f "$STATE/run/munged.ours" ] && stop_pidfile /run/munge/munged.pid
    if [ -L "$SYSTEM_CONF" ] && [ "$(readlink "$SYSTEM_CONF")" = "$STATE/slurm.conf" ]; then rm "$SYSTEM_CONF"; fi
    rm -rf "$STATE"
}

case "${1:-}" in
    up) up ;;
    down) down ;;
    status) status ;;
    *) echo "usage: $0 up|down|status" >&2; exit 2 ;;
esac
