#!/usr/bin/env bash
# A one-node Slurm on this machine, from Debian's packages, for trying the Monte Carlo job
# array locally and for its integration test (sim/tests/slurm.rs). Not for production.
#
#   local-cluster.sh install   apt-get install slurm-wlm munge (root or sudo)
#   local-cluster.sh start     start munged (if not running), slurmctld and slurmd; wait until
#                              the node is idle; print the SLURM_CONF to export
#   local-cluster.sh stop      stop what `start` started
#   local-cluster.sh status    sinfo and squeue
#
# Everything (configuration, state, logs, pid files) lives in $IANAV_SLURM_DIR (default
# /tmp/ianav-slurm); the daemons listen on 127.0.0.1 ports 16817 and 16818, so a system Slurm
# on the default ports is not disturbed. Needs no cgroups: processes are tracked through
# /proc (proctrack/linuxproc), tasks are not confined (task/none) and there is no accounting
# (use squeue and scontrol, not sacct). Every wait is bounded; re-running `start` on a running
# cluster only waits for the node.
set -euo pipefail

DIR=${IANAV_SLURM_DIR:-/tmp/ianav-slurm}
CONF=$DIR/slurm.conf
NODE=$(hostname -s)
WAIT_S=${IANAV_SLURM_WAIT_S:-60}
export SLURM_CONF=$CONF
PATH=$PATH:/usr/sbin:/sbin

die() { echo "local-cluster: $*" >&2; exit 1; }
as_root() {
  if [ "$(id -u)" = 0 ]; then "$@"
  elif command -v sudo >/dev/null 2>&1; then sudo "$@"
  else die "needs root (or sudo) for: $*"; fi
}
alive() { [ -f "$1" ] && kill -0 "$(cat "$1")" 2>/dev/null; }
munge_ok() { munge -n </dev/null 2>/dev/null | unmunge >/dev/null 2>&1; }

install() {
  if command -v slurmctld >/dev/null && command -v slurmd >/dev/null \
     && command -v sbatch >/dev/null && command -v munged >/dev/null; then
    echo "local-cluster: slurm-wlm and munge already installed"; return
  fi
  export DEBIAN_FRONTEND=noninteractive
  as_root apt-get update -qq
  as_root apt-get install -y -qq --no-install-recommends slurm-wlm munge >/dev/null
}

start_munge() {
  if munge_ok; then return; fi
  command -v munged >/dev/null || die "munged not found: run \`$0 install\`"
  [ -f /etc/munge/munge.key ] || as_root mungekey --create
  as_root mkdir -p /run/munge /var/log/munge /var/lib/munge
  as_root chown munge:munge /run/munge /var/log/munge /var/lib/munge /etc/munge/munge.key
  as_root runuser -u munge -- munged
  touch "$DIR/munged.started"
  for _ in $(seq 1 50); do munge_ok && return; sleep 0.2; done
  die "munged did not answer within 10 s"
}

write_conf() {
  local user; user=$(id -un)
  mkdir -p "$DIR/state" "$DIR/spool"
  cat >"$CONF" <<CONF
# Written by tools/slurm/local-cluster.sh: one node, no cgroups, no accounting.
ClusterName=ianav
SlurmctldHost=$NODE(127.0.0.1)
SlurmctldPort=16817
SlurmdPort=16818
AuthType=auth/munge
SlurmUser=$user
SlurmdUser=$user
StateSaveLocation=$DIR/state
SlurmdSpoolDir=$DIR/spool
SlurmctldPidFile=$DIR/slurmctld.pid
SlurmdPidFile=$DIR/slurmd.pid
SlurmctldLogFile=$DIR/slurmctld.log
SlurmdLogFile=$DIR/slurmd.log
ProctrackType=proctrack/linuxproc
TaskPlugin=task/none
JobAcctGatherType=jobacct_gather/none
AccountingStorageType=accounting_storage/none
JobCompType=jobcomp/none
SelectType=select/cons_tres
SelectTypeParameters=CR_CPU
MpiDefault=none
ReturnToService=2
SlurmdTimeout=60
NodeName=$NODE NodeAddr=127.0.0.1 CPUs=$(nproc) State=UNKNOWN
PartitionName=local Nodes=ALL Default=YES MaxTime=INFINITE State=UP
CONF
}

node_state() { sinfo -h -N -n "$NODE" -o %T 2>/dev/null | head -1; }

start() {
  command -v slurmctld >/dev/null || die "slurmctld not found: run \`$0 install\`"
  mkdir -p "$DIR"
  start_munge
  if ! alive "$DIR/slurmctld.pid" || ! alive "$DIR/slurmd.pid"; then
    stop_daemons
    write_conf
    # -c: a fresh controller, without jobs left from an earlier start.
    slurmctld -c -f "$CONF"
    slurmd -f "$CONF"
  fi
  local deadline=$((SECONDS + WAIT_S)) state=""
  while [ $SECONDS -lt $deadline ]; do
    state=$(node_state || true)
    case $state in
      idle*|mixed*|allocated*) echo "local-cluster: node $NODE $state; export SLURM_CONF=$CONF"; return ;;
      down*|drain*) scontrol update NodeName="$NODE" State=RESUME >/dev/null 2>&1 || true ;;
    esac
    sleep 0.5
  done
  echo "--- $DIR/slurmctld.log" >&2; tail -20 "$DIR/slurmctld.log" >&2 || true
  echo "--- $DIR/slurmd.log" >&2; tail -20 "$DIR/slurmd.log" >&2 || true
  die "node $NODE not idle within $WAIT_S s (state: ${state:-none})"
}

stop_pid() {
  local f=$1
  alive "$f" || { rm -f "$f"; return; }
  local pid; pid=$(cat "$f")
  kill "$pid" 2>/dev/null || true
  for _ in $(seq 1 50); do kill -0 "$pid" 2>/dev/null || { rm -f "$f"; return; }; sleep 0.2; done
  kill -9 "$pid" 2>/dev/null || true
  rm -f "$f"
}

stop_daemons() {
  stop_pid "$DIR/slurmd.pid"
  stop_pid "$DIR/slurmctld.pid"
}

stop() {
  stop_daemons
  if [ -f "$DIR/munged.started" ]; then
    stop_pid /run/munge/munged.pid
    rm -f "$DIR/munged.started"
  fi
  echo "local-cluster: stopped"
}

case ${1:-} in
  install) install ;;
  start) start ;;
  stop) stop ;;
  status) sinfo; squeue ;;
  *) die "usage: $0 install|start|stop|status" ;;
esac
