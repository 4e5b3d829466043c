#!/usr/bin/env bash
# Several emulated hosts on this machine, joined by network links, running one real-time test.
#
#   bash tools/hosts.sh [--partition loop_local|builder_remote] [--processes loop|node]
#                       [--delay-ms D] [--jitter-ms J]
#                       [--loss P] [--link SITE=D[,J[,P]]]... [--cut-after S] [--cut-site SITE]
#                       [--live PORT] [--live-stop]
#                       [--out DIR | --name NAME] [-- seft run options (a config, --alpha, ...)]
#
# The outputs go to --out DIR (new or empty), else to runs/NAME (default NAME: hosts), or
# runs/NAME-2, -3, ... where that exists, as seft run --name picks its folder.
# One network namespace per site of the partition (`seft sites`): "compute" (the recorder
# and the ground-motion publisher; with builder_remote the builder too) and one per lab
# ("lab" for the study's rig, or one per rig of a structure, named after it). Each lab's link
# to the compute host has its own one-way delay, jitter (half-width of a uniform jitter) and
# loss (--link SITE=D,J,P; --delay-ms/--jitter-ms/--loss for every lab otherwise); lab to lab
# goes through the compute host (a star). The links: a user-space hub (the link emulator,
# seft_ros.cli.link_emulator: one TUN device per namespace; this kernel has no netem), the
# namespaces' own addresses, multicast routed to the link (Fast DDS's discovery), UDP only
# (shared memory would bypass the link). Each site runs
# `seft run --mode realtime --partition P --site SITE ...`: the runners measure the links
# (round trip, clock offset), agree on the playout delay and preview, and the compute host
# writes the bag and the report. Each lab's loop (its rig, force servo controller and
# builder) runs in one process (--processes loop, the default: the bridge over three hosts
# on two cores completed every run with it, and missed deadlines without; docs/network.md);
# --processes node runs one process per node. --cut-after S cuts a lab's link (both ways,
# in the link emulator) S seconds after the rigs started (--cut-site, default the first lab).
# At the end it prints what each host's kernel lost (UDP receive-buffer overflows, the link
# device's drops). --live PORT starts the live view on the compute host (seft run --live:
# Foxglove at PORT, the web page at PORT+1; --live-stop adds the operator's stop button)
# and forwards both ports from this machine's 127.0.0.1 into its namespace
# (tools/netns_forward.py); the URLs are printed once it listens.
# Everything this script creates is removed at the end, also on Ctrl-C or failure. Needs root
# (ip netns, /dev/net/tun).
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
partition=loop_local processes=loop delay=0 jitter=0 loss=0 cut="" cut_site="" live="" live_stop=""
out="" name=hosts
declare -A links=()
usage() { sed -n '2,34p' "$0"; }
while [[ $# -gt 0 ]]; do
  case "$1" in
    --partition) partition="$2"; shift 2 ;;
    --processes) processes="$2"; shift 2 ;;
    --delay-ms) delay="$2"; shift 2 ;;
    --jitter-ms) jitter="$2"; shift 2 ;;
    --loss) loss="$2"; shift 2 ;;
    --link) links["${2%%=*}"]="${2#*=}"; [[ "$2" == *=* ]] || { echo "hosts.sh: error: --link $2: expected SITE=DELAY_MS[,JITTER_MS[,LOSS]]" >&2; exit 2; }; shift 2 ;;
    --cut-after) cut="$2"; shift 2 ;;
    --cut-site) cut_site="$2"; shift 2 ;;
    --out) out="$2"; shift 2 ;;
    --name) name="$2"; shift 2 ;;
    --live) live="$2"; shift 2 ;;
    --live-stop) live_stop=1; shift ;;
    --) shift; break ;;
    -h|--help) usage; exit 0 ;;
    *) echo "hosts.sh: error: unknown option $1 (seft run options go after --)" >&2; exit 2 ;;
  esac
done
if [[ -n "$out" ]]; then
  [[ ! -e "$out" || ( -d "$out" && -z "$(ls -A "$out")" ) ]] || { echo "hosts.sh: error: --out $out: exists and is not empty; expected a new directory (without --out: runs/$name, or runs/$name-2, ... where that exists)" >&2; exit 2; }
else
  [[ "$name" =~ ^[A-Za-z0-9._-]+$ && "$name" != . && "$name" != .. ]] || { echo "hosts.sh: error: --name $name: expected a name, not a path (letters, digits, . _ -)" >&2; exit 2; }
  out="$root/runs/$name" i=1
  while [[ -e "$out" ]]; do i=$((i + 1)); out="$root/runs/$name-$i"; done
fi
[[ "$processes" == loop || "$processes" == node ]] || { echo "hosts.sh: error: --processes $processes: expected loop or node" >&2; exit 2; }
number() { [[ "$1" =~ ^[0-9]+([.][0-9]+)?$ ]] || { echo "hosts.sh: error: '$1': expected a number >= 0 ($2)" >&2; exit 2; }; }
number "$delay" --delay-ms; number "$jitter" --jitter-ms; number "$loss" --loss
[[ -z "$cut" ]] || number "$cut" --cut-after
[[ -z "$live" || ( "$live" =~ ^[0-9]+$ && "$live" -ge 1 && "$live" -le 65534 ) ]] || { echo "hosts.sh: error: --live $live: expected a port 1-65534 (the web page takes PORT+1)" >&2; exit 2; }
[[ -z "$live_stop" || -n "$live" ]] || { echo "hosts.sh: error: --live-stop needs --live PORT" >&2; exit 2; }
[[ "$(id -u)" == 0 ]] || { echo "hosts.sh: error: needs root (ip netns, /dev/net/tun); run it as root" >&2; exit 2; }
command -v ip >/dev/null || { echo "hosts.sh: error: iproute2 (ip) is not installed" >&2; exit 2; }
py="$root/.venv/bin/python"
seft="$root/.venv/bin/seft"
[[ -x "$seft" ]] || { echo "hosts.sh: error: $seft missing: run bash tools/setup.sh first" >&2; exit 2; }

# the sites of the partition, as seft sees the run's options (one line "site: nodes" each)
site_lines="$("$seft" sites --partition "$partition" "$@")" || exit 2
mapfile -t sites < <(printf '%s\n' "$site_lines" | cut -d: -f1)
labs=()
for s in "${sites[@]}"; do [[ "$s" == compute ]] || labs+=("$s"); done
for s in "${!links[@]}"; do
  [[ " ${labs[*]} " == *" $s "* ]] || { echo "hosts.sh: error: --link $s: not a lab site of partition $partition (sites: ${labs[*]})" >&2; exit 2; }
done
[[ -z "$cut_site" || " ${labs[*]} " == *" $cut_site "* ]] || { echo "hosts.sh: error: --cut-site $cut_site: not a lab site (sites: ${labs[*]})" >&2; exit 2; }
[[ -n "$cut_site" ]] || cut_site="${labs[0]}"

id=$$
net="10.$((200 + id % 50)).$(( (id / 50) % 250))"
declare -A ns dev addr
ports=()
k=0
for s in compute "${labs[@]}"; do
  k=$((k + 1))
  ns[$s]="seft-$k-$id"
  dev[$s]="sh$(printf %06d $((id % 1000000)))$k"
  addr[$s]="$net.$k"
  if [[ "$s" == compute ]]; then
    ports+=(--port "${dev[$s]},${addr[$s]},0,0,0")
  else
    IFS=, read -r d j p <<< "${links[$s]:-$delay,$jitter,$loss}"
    d="${d:-$delay}" j="${j:-0}" p="${p:-0}"
    number "$d" "--link $s delay"; number "$j" "--link $s jitter"; number "$p" "--link $s loss"
    links[$s]="$d,$j,$p"
    ports+=(--port "${dev[$s]},${addr[$s]},$d,$j,$p")
  fi
done

hub=""
forward=""
cleanup() {
  trap - EXIT INT TERM
  if [[ -n "$forward" ]]; then kill -TERM "$forward" 2>/dev/null || true; fi
  for s in "${!ns[@]}"; do ip netns pids "${ns[$s]}" 2>/dev/null | xargs -r kill -INT 2>/dev/null || true; done
  sleep 2
  for s in "${!ns[@]}"; do
    ip netns pids "${ns[$s]}" 2>/dev/null | xargs -r kill -KILL 2>/dev/null || true
    # also deletes the devices in it; a namespace still being torn down can refuse (EBUSY)
    for _ in $(seq 20); do
      ip netns del "${ns[$s]}" 2>/dev/null || true
      ip netns list | grep -qw "${ns[$s]}" || break
      sleep 0.25
    done
    ip netns list | grep -qw "${ns[$s]}" && echo "hosts.sh: warning: could not remove network namespace ${ns[$s]}" >&2
  done
  if [[ -n "$hub" ]]; then kill -INT "$hub" 2>/dev/null || true; wait "$hub" 2>/dev/null || true; fi
}
trap cleanup EXIT
trap 'echo "hosts.sh: interrupted" >&2; exit 130' INT TERM

for s in "${!ns[@]}"; do ip netns add "${ns[$s]}"; ip -n "${ns[$s]}" link set lo up; done
mkdir -p "$out"
ready="$(mktemp -u)"
"$py" -m seft_ros.cli.link_emulator "${ports[@]}" ${cut:+--cut-on-signal "${dev[$cut_site]}"} \
  --ready-file "$ready" 2> "$out/link_emulator.err" &
hub=$!
for _ in $(seq 100); do [[ -s "$ready" ]] && break; kill -0 "$hub" 2>/dev/null || break; sleep 0.1; done
[[ -s "$ready" ]] || { echo "hosts.sh: error: the link emulator did not start: $(tail -1 "$out/link_emulator.err")" >&2; exit 1; }
rm -f "$ready"
for s in "${!ns[@]}"; do
  ip link set "${dev[$s]}" netns "${ns[$s]}"
  ip -n "${ns[$s]}" addr add "${addr[$s]}/24" dev "${dev[$s]}"
  ip -n "${ns[$s]}" link set "${dev[$s]}" multicast on up
  ip -n "${ns[$s]}" route add 224.0.0.0/4 dev "${dev[$s]}"
done

domain=$((100 + RANDOM % 100))
emulation="link emulator"
summary="link: $emulation (a hub at compute);"
for s in "${labs[@]}"; do IFS=, read -r d j p <<< "${links[$s]}"; summary+=" $s ${d} ms +/- ${j} ms loss $p;"; done
echo "hosts.sh: partition $partition, processes $processes, domain $domain, network namespaces seft-*-$id; $summary" >&2

pids=()
launched="$EPOCHREALTIME"
for s in compute "${labs[@]}"; do
  viewer=()
  if [[ "$s" == compute && -n "$live" ]]; then
    viewer=(--live "127.0.0.1:$live" ${live_stop:+--live-stop})
  fi
  ip netns exec "${ns[$s]}" env ROS_DOMAIN_ID="$domain" ROS_AUTOMATIC_DISCOVERY_RANGE=SUBNET \
    FASTDDS_BUILTIN_TRANSPORTS=UDPv4 PYTHONUNBUFFERED=1 SEFT_SITE="$s" \
    SEFT_LINK_EMULATION="$emulation" "$seft" run --mode realtime --partition "$partition" \
    --processes "$processes" --site "$s" "${viewer[@]}" "$@" --out "$out/$s" > "$out/$s.txt" \
    2> "$out/$s.err" &
  pids+=($!)
done
if [[ -n "$live" ]]; then
  # the compute host's live view, reached from this machine's 127.0.0.1
  "$py" "$root/tools/netns_forward.py" "${ns[compute]}" "$live" "$((live + 1))" &
  forward=$!
  for _ in $(seq 300); do
    grep -q 'live view: \(Foxglove\|off\)' "$out/compute.err" 2>/dev/null && break
    sleep 0.1
  done
  grep -h 'live view: ' "$out/compute.err" | sed 's/^\[seft\] /hosts.sh: compute: /' >&2 || true
fi

if [[ -n "$cut" ]]; then
  # The cut is timed from the rig's own "starting" line (the wall time of its sample 0), not
  # from when this script saw it: with the graph's nodes on SCHED_FIFO and the host busy, a
  # normal process (this script, grep, sleep) was seen to wake 1-1.5 s late, and the cut,
  # asked for 1 s after the start, came 2.5 s after it. The watcher runs above the graph's
  # priorities (SCHED_FIFO 99, where this host allows it; it sleeps nearly all the time) and
  # cuts the wire, not the device: the link emulator drops the lab's packets from SIGUSR1 on
  # ('ip link set DEV down' waits for the kernel's RCU grace periods, which the saturated
  # host stretched: the cut came 40-170 ms after the command). No fork between the wake-up
  # and the cut (bash's own clock and kill).
  (
    chrt -f -p 99 "$BASHPID" >/dev/null 2>&1 || true
    start=""
    for _ in $(seq 6000); do
      start="$(grep -hs -m1 'starting (' "$out/$cut_site"/*/logs/*rig.log \
               | sed -n 's/^[^[]*\[[A-Z]*\] \[\([0-9.]*\)\].*/\1/p' | head -n1)" || true
      # a rig of this run: started after its runners were (never another run's log)
      [[ -z "$start" ]] || awk -v t="$start" -v l="$launched" 'BEGIN { exit !(t >= l - 1) }' || start=""
      [[ -z "$start" ]] || break
      alive=0; for p in "${pids[@]}"; do kill -0 "$p" 2>/dev/null && alive=1; done
      [[ $alive == 1 ]] || break                 # every runner gone: no rig will start
      sleep 0.02
    done
    [[ -n "$start" ]] || { echo "hosts.sh: no rig of $cut_site started: link not cut" >&2; exit 0; }
    wait_s="$(awk -v t0="$start" -v c="$cut" -v now="$EPOCHREALTIME" 'BEGIN { d = t0 + c - now; printf "%.3f", (d > 0 ? d : 0) }')"
    sleep "$wait_s"
    kill -USR1 "$hub" 2>/dev/null || { echo "hosts.sh: the link emulator is gone: link not cut" >&2; exit 0; }
    at="$EPOCHREALTIME"
    echo "hosts.sh: link cut (${dev[$cut_site]} of $cut_site, both ways) $(awk -v t0="$start" -v t="$at" 'BEGIN { printf "%.3f", t - t0 }') s after the rigs started (asked: $cut s), at wall time ${at/./}000 ns" >&2
  )
fi
rc=0
i=0
: > "$out/exits.txt"
for s in compute "${labs[@]}"; do
  code=0
  wait "${pids[$i]}" || code=$?
  [[ $code == 0 ]] || rc=1
  echo "$s exit $code" >> "$out/exits.txt"
  i=$((i + 1))
done
# what each host's kernel lost: UDP datagrams dropped for a full socket buffer (a process too
# busy to read, DDS then resends) and packets its link device dropped on the way in
for s in compute "${labs[@]}"; do
  udp="$(ip netns exec "${ns[$s]}" awk '/^Udp:/ { if (h) { for (i = 2; i <= NF; i++) v[n[i]] = $i } else { h = 1; for (i = 2; i <= NF; i++) n[i] = $i } } END { printf "%s received, %s receive-buffer overflows, %s in errors", v["InDatagrams"], v["RcvbufErrors"], v["InErrors"] }' /proc/net/snmp 2>/dev/null)" || udp="not read"
  rxdrop="$(ip netns exec "${ns[$s]}" cat "/sys/class/net/${dev[$s]}/statistics/rx_dropped" 2>/dev/null)" || rxdrop=""
  echo "hosts.sh: $s: UDP $udp; link device ${rxdrop:-?} packets dropped in" >&2
done
for s in compute "${labs[@]}"; do
  grep -v -e RTPS_TRANSPORT_SHM -e '^\s*$' "$out/$s.err" | sed "s/^/$s: /" >&2 || true
done
cat "$out/compute.txt"
kill -INT "$hub" 2>/dev/null || true
wait "$hub" 2>/dev/null || true
hub=""
grep -v '^\s*$' "$out/link_emulator.err" >&2 || true
echo "$summary${cut:+ cut $cut_site after $cut s}"
echo "exits: $(sed ':a;N;$!ba;s/\n/, /g' "$out/exits.txt"); outputs in $out"
exit $rc
