#!/usr/bin/env bash
# Two emulated hosts on this machine, joined by a network link, running one real-time test.
#
#   bash tools/two_hosts.sh [--delay-ms D] [--jitter-ms J] [--loss P] [--cut-after S]
#                           [--out DIR] [-- seft run options]
#
# Network namespaces "lab" (rig, force servo controller) and "compute" (ground-motion
# publisher, reference-force builder, recorder), a link between them with the namespaces'
# own addresses, multicast routed to it (Fast DDS's default discovery), UDP only (shared
# memory would bypass the link). Each side runs `seft run --mode realtime --nodes ...`.
# The link: `tc netem` on the veth where the kernel has it; else two TUN devices joined by the
# link emulator (seft_ros.cli.link_emulator: a user-space wire that delays, jitters and drops
# the packets). One ROS domain, as on a real network. --cut-after S takes the lab's link
# device down S seconds after the rig started. Everything this script creates is removed at
# the end, also on Ctrl-C or failure. Needs root (ip netns).
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
delay=0 jitter=0 loss=0 cut=""
out="$root/runs/two_hosts"
while [[ $# -gt 0 ]]; do
  case "$1" in
    --delay-ms) delay="$2"; shift 2 ;;
    --jitter-ms) jitter="$2"; shift 2 ;;
    --loss) loss="$2"; shift 2 ;;
    --cut-after) cut="$2"; shift 2 ;;
    --out) out="$2"; shift 2 ;;
    --) shift; break ;;
    -h|--help) sed -n '2,15p' "$0"; exit 0 ;;
    *) echo "two_hosts.sh: error: unknown option $1 (seft run options go after --)" >&2; exit 2 ;;
  esac
done
for v in "$delay" "$jitter" "$loss" ${cut:+"$cut"}; do
  [[ "$v" =~ ^[0-9]+([.][0-9]+)?$ ]] || { echo "two_hosts.sh: error: '$v': expected a number >= 0" >&2; exit 2; }
done
[[ "$(id -u)" == 0 ]] || { echo "two_hosts.sh: error: needs root (ip netns, veth); run it as root" >&2; exit 2; }
command -v ip >/dev/null || { echo "two_hosts.sh: error: iproute2 (ip) is not installed" >&2; exit 2; }
py="$root/.venv/bin/python"
seft="$root/.venv/bin/seft"
[[ -x "$seft" ]] || { echo "two_hosts.sh: error: $seft missing: run bash tools/setup.sh first" >&2; exit 2; }

id=$$
lab="seft-lab-$id" cmp="seft-cmp-$id"
net="10.231.$((id % 250)).0"
addr_lab="${net%.0}.1" addr_cmp="${net%.0}.2"
relay=""
cleanup() {
  trap - EXIT INT TERM
  for ns in "$lab" "$cmp"; do
    ip netns pids "$ns" 2>/dev/null | xargs -r kill -INT 2>/dev/null || true
  done
  sleep 2
  for ns in "$lab" "$cmp"; do
    ip netns pids "$ns" 2>/dev/null | xargs -r kill -KILL 2>/dev/null || true
    ip netns del "$ns" 2>/dev/null || true      # also deletes the devices in it
  done
  if [[ -n "$relay" ]]; then kill -INT "$relay" 2>/dev/null || true; wait "$relay" 2>/dev/null || true; fi
}
trap cleanup EXIT
trap 'echo "two_hosts.sh: interrupted" >&2; exit 130' INT TERM

ip netns add "$lab"
ip netns add "$cmp"
for ns in "$lab" "$cmp"; do ip -n "$ns" link set lo up; done

# the link: a veth pair (with netem on both ends if asked and the kernel has it), else two
# TUN devices joined by the link emulator, a user-space wire that delays, jitters and drops
dev_lab="sl$id" dev_cmp="sc$id"
ip link add "$dev_lab" type veth peer name "$dev_cmp"
ip link set "$dev_lab" netns "$lab"
ip link set "$dev_cmp" netns "$cmp"
emulator=none
if [[ "$delay" != 0 || "$jitter" != 0 || "$loss" != 0 ]]; then
  pct=$(awk "BEGIN{print 100*$loss}")
  if ip netns exec "$lab" tc qdisc add dev "$dev_lab" root netem delay "${delay}ms" "${jitter}ms" loss "${pct}%" 2>/dev/null \
     && ip netns exec "$cmp" tc qdisc add dev "$dev_cmp" root netem delay "${delay}ms" "${jitter}ms" loss "${pct}%" 2>/dev/null; then
    emulator=netem
  else
    emulator="link emulator (user-space packet wire; this kernel has no netem)"
    ip -n "$lab" link del "$dev_lab"
    dev_lab="tl$id" dev_cmp="tc$id"
    ready="$(mktemp -u)"
    "$py" -m seft_ros.cli.link_emulator --devices "$dev_lab" "$dev_cmp" --delay-ms "$delay" \
      --jitter-ms "$jitter" --loss "$loss" --ready-file "$ready" &
    relay=$!
    for _ in $(seq 100); do [[ -s "$ready" ]] && break; kill -0 "$relay" 2>/dev/null || break; sleep 0.1; done
    [[ -s "$ready" ]] || { echo "two_hosts.sh: error: the link emulator did not start" >&2; exit 1; }
    rm -f "$ready"
    ip link set "$dev_lab" netns "$lab"
    ip link set "$dev_cmp" netns "$cmp"
  fi
fi
ip -n "$lab" addr add "$addr_lab/24" dev "$dev_lab"
ip -n "$cmp" addr add "$addr_cmp/24" dev "$dev_cmp"
for pair in "$lab:$dev_lab" "$cmp:$dev_cmp"; do
  ns="${pair%%:*}" dev="${pair##*:}"
  ip -n "$ns" link set "$dev" multicast on up
  ip -n "$ns" route add 224.0.0.0/4 dev "$dev"
done

domain=$((100 + RANDOM % 100))
echo "two_hosts.sh: lab $lab ($addr_lab), compute $cmp ($addr_cmp), domain $domain; link: $emulator, delay ${delay} ms +/- ${jitter} ms, loss $loss" >&2

env_common=(ROS_DOMAIN_ID="$domain" ROS_AUTOMATIC_DISCOVERY_RANGE=SUBNET FASTDDS_BUILTIN_TRANSPORTS=UDPv4 PYTHONUNBUFFERED=1)
mkdir -p "$out"
ip netns exec "$cmp" env "${env_common[@]}" "$seft" run \
  --mode realtime --nodes recorder,ground_motion_publisher,reference_force_builder "$@" \
  --out "$out/compute" > "$out/compute.txt" 2> "$out/compute.err" &
compute=$!
ip netns exec "$lab" env "${env_common[@]}" "$seft" run \
  --mode realtime --nodes rig,force_servo_controller "$@" --out "$out/lab" \
  > "$out/lab.txt" 2> "$out/lab.err" &
labpid=$!

if [[ -n "$cut" ]]; then
  for _ in $(seq 1200); do
    if grep -qs 'starting (' "$out"/lab/*/logs/rig.log; then break; fi
    sleep 0.1
  done
  sleep "$cut"
  ip -n "$lab" link set "$dev_lab" down
  echo "two_hosts.sh: link cut ($dev_lab down) $cut s after the rig started, at wall time $(date +%s%N) ns" >&2
fi
rc_cmp=0 rc_lab=0
wait "$compute" || rc_cmp=$?
wait "$labpid" || rc_lab=$?
grep -v -e RTPS_TRANSPORT_SHM -e '^\s*$' "$out/compute.err" | sed 's/^/compute: /' >&2 || true
grep -v -e RTPS_TRANSPORT_SHM -e '^\s*$' "$out/lab.err" | sed 's/^/lab: /' >&2 || true
cat "$out/compute.txt"
echo "link: $emulator; delay ${delay} ms +/- ${jitter} ms, loss $loss${cut:+; cut after $cut s}"
echo "lab exit $rc_lab, compute exit $rc_cmp; outputs in $out"
[[ $rc_cmp == 0 && $rc_lab == 0 ]] || exit 1
