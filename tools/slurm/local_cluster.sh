#!/usr/bin/env bash
# A one-machine Slurm cluster on loopback, in a folder of its own: munge with a generated key,
# slurmctld and slurmd from a config written there, no cgroups. For tests and for trying
# `refocus batch submit` without a farm. Run as root (SlurmUser=root).
#   tools/slurm/local_cluster.sh start DIR [PORT]   prints the lines to source (SLURM_CONF, ...)
#   tools/slurm/local_cluster.sh stop DIR
# Exit 3 when the daemons cannot start here (the caller says why and skips).
set -uo pipefail
cmd=${1:-}; dir=${2:-}
[ -n "$cmd" ] && [ -n "$dir" ] || { echo "usage: $0 start|stop DIR [PORT]" >&2; exit 2; }

stop() {
  for f in slurmd.pid slurmctld.pid munged.pid; do
    [ -f "$dir/$f" ] && kill "$(cat "$dir/$f")" 2>/dev/null
  done
  sleep 1
  for f in slurmd.pid slurmctld.pid munged.pid; do
    [ -f "$dir/$f" ] && kill -9 "$(cat "$dir/$f")" 2>/dev/null
    rm -f "$dir/$f"
  done
  return 0
}
if [ "$cmd" = stop ]; then stop; exit 0; fi
[ "$cmd" = start ] || { echo "usage: $0 start|stop DIR [PORT]" >&2; exit 2; }

for b in munged slurmctld slurmd sbatch sinfo; do
  command -v "$b" >/dev/null || { echo "local_cluster: $b is not installed (slurm-wlm, munge)" >&2; exit 3; }
done
[ "$(id -u)" = 0 ] || { echo "local_cluster: needs root (SlurmUser=root)" >&2; exit 3; }

dir=$(mkdir -p "$dir" && cd "$dir" && pwd)
chmod 700 "$dir"
mkdir -p "$dir/state" "$dir/spool" "$dir/log"
port=${3:-$((20000 + RANDOM % 20000))}
host=$(hostname -s)
cpus=$(nproc)
mem=$(awk '/MemTotal/ {print int($2/1024) - 1024}' /proc/meminfo)

dd if=/dev/urandom of="$dir/munge.key" bs=1024 count=1 status=none
chmod 600 "$dir/munge.key"
munged --force --key-file="$dir/munge.key" --socket="$dir/munge.socket" \
  --pid-file="$dir/munged.pid" --log-file="$dir/log/munged.log" --seed-file="$dir/munged.seed" \
  || { echo "local_cluster: munged did not start (see $dir/log/munged.log)" >&2; exit 3; }

cat >"$dir/slurm.conf" <<CONF
ClusterName=refocus-local
SlurmctldHost=$host(127.0.0.1)
SlurmUser=root
SlurmdUser=root
AuthType=auth/munge
CredType=cred/munge
AuthInfo=socket=$dir/munge.socket
SlurmctldPort=$port
SlurmdPort=$((port + 1))
StateSaveLocation=$dir/state
SlurmdSpoolDir=$dir/spool
SlurmctldPidFile=$dir/slurmctld.pid
SlurmdPidFile=$dir/slurmd.pid
SlurmctldLogFile=$dir/log/slurmctld.log
SlurmdLogFile=$dir/log/slurmd.log
ProctrackType=proctrack/linuxproc
TaskPlugin=task/none
JobAcctGatherType=jobacct_gather/none
AccountingStorageType=accounting_storage/none
SelectType=select/cons_tres
SelectTypeParameters=CR_Core_Memory
SchedulerType=sched/backfill
SchedulerParameters=sched_interval=1
MinJobAge=600
ReturnToService=2
KillWait=5
MailProg=/bin/true
NodeName=$host NodeAddr=127.0.0.1 CPUs=$cpus RealMemory=$mem State=UNKNOWN
PartitionName=local Nodes=$host Default=YES MaxTime=INFINITE State=UP OverSubscribe=NO
CONF
export SLURM_CONF="$dir/slurm.conf"
slurmctld -f "$dir/slurm.conf" || { echo "local_cluster: slurmctld did not start (see $dir/log/slurmctld.log)" >&2; stop; exit 3; }
slurmd -f "$dir/slurm.conf" || { echo "local_cluster: slurmd did not start (see $dir/log/slurmd.log)" >&2; stop; exit 3; }
for _ in $(seq 60); do
  if sinfo -h -o %T 2>/dev/null | grep -qx idle; then
    echo "export SLURM_CONF=$dir/slurm.conf"
    exit 0
  fi
  sleep 0.5
done
echo "local_cluster: the node did not come up idle in 30 s (see $dir/log/)" >&2
sinfo >&2
stop
exit 3
