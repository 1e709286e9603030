#!/bin/sh
# Run a command in a private network namespace that has only loopback (up, with multicast
# and a multicast route, so DDS discovery works) and a private /dev/shm (Fast DDS's shared
# memory segments stay in it). No packet can leave the machine's loopback. Needs root, or
# user namespaces (then it maps the caller to root inside).
set -eu
if [ "${FPGALINK_IN_NETNS:-}" != 1 ]; then
    FPGALINK_IN_NETNS=1
    export FPGALINK_IN_NETNS
    if [ "$(id -u)" = 0 ]; then
        exec unshare --net --mount --propagation private -- "$0" "$@"
    fi
    exec unshare --net --mount --map-root-user --propagation private -- "$0" "$@"
fi
ip link set lo up
ip link set lo multicast on
ip route add 224.0.0.0/4 dev lo
mount -t tmpfs -o mode=1777,size=256m fpgalink_ros2_shm /dev/shm
others=$(ip -o link show | awk -F': ' '{print $2}' | grep -v '^lo$' || true)
if [ -n "$others" ]; then
    echo "netns.sh: refusing to run: interfaces other than lo: $others" >&2
    exit 97
fi
exec "$@"
