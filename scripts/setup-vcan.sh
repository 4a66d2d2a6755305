#!/usr/bin/env bash
# Create and bring up a SocketCAN virtual bus (default vcan0) on a Linux machine whose kernel has CAN.
# Usage: sudo scripts/setup-vcan.sh [NAME]
set -euo pipefail
name="${1:-vcan0}"
if [ "$(id -u)" -ne 0 ]; then
    echo "setup-vcan: needs root (try: sudo $0 $name)" >&2
    exit 1
fi
if ! modprobe vcan 2>/dev/null; then
    echo "setup-vcan: cannot load the vcan module; this kernel may be built without CAN (CONFIG_CAN_VCAN)" >&2
    exit 1
fi
if ip link show "$name" >/dev/null 2>&1; then
    echo "setup-vcan: $name exists"
else
    ip link add dev "$name" type vcan
fi
ip link set up "$name"
ip -details link show "$name"
echo "setup-vcan: $name is up"
