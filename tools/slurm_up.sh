#!/usr/bin/env bash
# Starts a single-node Slurm cluster on this machine for the farm tests
# (munge + slurmctld + slurmd on localhost, one partition "main" with every
# core), installing Debian's slurm-wlm and munge first if needed.
# Idempotent: a running cluster is left as it is. Run as root (or with sudo).
#
#   bash tools/slurm_up.sh
set -euo pipefail
SUDO=""; [ "$(id -u)" = 0 ] || SUDO="sudo"
if ! command -v slurmctld >/dev/null || ! command -v munged >/dev/null; then
  echo "== installing slurm-wlm and munge"
  $SUDO apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq slurm-wlm munge >/dev/null
fi
if sinfo -h -o %T 2>/dev/null | grep -qE "idle|mixed|allocated"; then
  echo "== Slurm already up: $(sinfo -h -o '%P %D %T %c')"
  exit 0
fi
host=$(hostname -s)
cpus=$(nproc)
mem=$(( $(awk '/MemTotal/ {print $2}' /proc/meminfo) / 1024 - 1024 ))

# munge: the authentication every Slurm message carries.
$SUDO mkdir -p /run/munge /var/log/munge /var/lib/munge
[ -s /etc/munge/munge.key ] || $SUDO /usr/sbin/mungekey --create >/dev/null 2>&1 || \
  $SUDO dd if=/dev/urandom of=/etc/munge/munge.key bs=1 count=1024 status=none
$SUDO chown -R munge:munge /etc/munge /run/munge /var/log/munge /var/lib/munge
$SUDO chmod 0700 /etc/munge /var/log/munge /var/lib/munge
$SUDO chmod 0755 /run/munge
$SUDO chmod 0400 /etc/munge/munge.key
pgrep -x munged >/dev/null || $SUDO runuser -u munge -- /usr/sbin/munged

# Slurm: no cgroups (containers rarely delegate them), no accounting database.
$SUDO mkdir -p /etc/slurm /var/spool/slurmctld /var/spool/slurmd /var/log/slurm
$SUDO tee /etc/slurm/slurm.conf >/dev/null <<CONF
ClusterName=nst3d
SlurmctldHost=$host
SlurmUser=root
SlurmdUser=root
AuthType=auth/munge
ProctrackType=proctrack/linuxproc
TaskPlugin=task/none
SelectType=select/cons_tres
SelectTypeParameters=CR_Core
SchedulerType=sched/backfill
JobAcctGatherType=jobacct_gather/none
AccountingStorageType=accounting_storage/none
MpiDefault=none
ReturnToService=2
StateSaveLocation=/var/spool/slurmctld
SlurmdSpoolDir=/var/spool/slurmd
SlurmctldLogFile=/var/log/slurm/slurmctld.log
SlurmdLogFile=/var/log/slurm/slurmd.log
SlurmctldPidFile=/run/slurmctld.pid
SlurmdPidFile=/run/slurmd.pid
JobRequeue=1
NodeName=$host CPUs=$cpus RealMemory=$mem State=UNKNOWN
PartitionName=main Nodes=$host Default=YES MaxTime=INFINITE State=UP OverSubscribe=YES
CONF
pgrep -x slurmctld >/dev/null || $SUDO /usr/sbin/slurmctld
# A slurmd started before MPI's PMIx library was installed cannot launch
# `srun --mpi=pmix` steps: start it again, its log afresh.
if pgrep -x slurmd >/dev/null && grep -qs "can not load PMIx library" /var/log/slurm/slurmd.log; then
  $SUDO pkill -x slurmd || true
  for _ in $(seq 50); do pgrep -x slurmd >/dev/null || break; sleep 0.2; done
  $SUDO pkill -9 -x slurmd || true
  sleep 0.5
  $SUDO rm -f /var/log/slurm/slurmd.log
fi
pgrep -x slurmd >/dev/null || $SUDO /usr/sbin/slurmd
for _ in $(seq 60); do
  if sinfo -h -o %T 2>/dev/null | grep -qE "idle|mixed|allocated"; then
    echo "== Slurm up: $(sinfo -h -o '%P %D %T %c')"
    exit 0
  fi
  sleep 1
done
echo "Slurm did not come up; logs:" >&2
tail -20 /var/log/slurm/slurmctld.log /var/log/slurm/slurmd.log >&2 || true
exit 1
