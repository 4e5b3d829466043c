#!/usr/bin/env bash
# Two emulated hosts on this machine, joined by a network link, running one real-time test:
# tools/hosts.sh with the study's single rig (a "lab" host and a "compute" host).
#
#   bash tools/two_hosts.sh [--partition loop_local|builder_remote] [--processes loop|node]
#                           [--delay-ms D]
#                           [--jitter-ms J] [--loss P] [--cut-after S] [--out DIR]
#                           [--live PORT] [--live-stop]
#                           [-- seft run options]
#
# The default partition is loop_local: the lab host runs the rig, the force servo controller
# and the reference-force builder with its compensator (the loop closes there, the network
# out of it), the compute host the ground-motion publisher (its samples reach the lab ahead
# of their use) and the recorder. --partition builder_remote is the earlier split (the
# builder on the compute host, the loop across the link with a playout delay the runners
# size from the measured round trip). --live PORT: the live view of the compute host, at
# 127.0.0.1:PORT (Foxglove) and PORT+1 (the page). The outputs go to --out DIR (new or
# empty), else to runs/two_hosts, or runs/two_hosts-2, -3, ... where that exists. See
# tools/hosts.sh for the rest (it needs root).
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
out=()
args=()
while [[ $# -gt 0 ]]; do
  case "$1" in
    --out) out=(--out "$2"); shift 2 ;;
    --) break ;;
    -h|--help) sed -n '2,19p' "$0"; exit 0 ;;
    *) args+=("$1"); shift ;;
  esac
done
[[ ${#out[@]} -gt 0 ]] || out=(--name two_hosts)
exec bash "$root/tools/hosts.sh" "${out[@]}" "${args[@]}" "$@"
