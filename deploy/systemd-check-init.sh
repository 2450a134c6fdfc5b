#!/bin/sh
# PID 1 of the systemd check container: make the devices a Pi has, then become systemd.
# A Pi's kernel registers the device groups the unit's DeviceAllow= names (video4linux: the camera
# driver; ttyUSB / ttyACM: USB serial adapters and flight controllers) in /proc/devices, and systemd
# resolves DeviceAllow=char-NAME through that file when the service starts. This machine's kernel has
# none of those drivers, so the groups are added to a copy of /proc/devices bound over it, and
# device nodes are made with their Linux major numbers. Opening a node whose driver is absent fails
# with ENXIO / ENODEV; a node the unit's device policy blocks fails with EPERM: that is what the check
# tells apart. /dev/jsar-blocked (misc 10:200, not in the unit's list) is the negative control.
set -eu
extra=""
grep -q ' video4linux$' /proc/devices || extra="$extra 81 video4linux\n"
grep -q ' ttyACM$' /proc/devices || extra="${extra}166 ttyACM\n"
grep -q ' ttyUSB$' /proc/devices || extra="${extra}188 ttyUSB\n"
printf "$extra" > /run/devices-extra
sed '/^Character devices:/r /run/devices-extra' /proc/devices > /run/devices
mount --bind /run/devices /proc/devices
make_node() {  # path type major minor group
    [ -e "$1" ] || mknod -m 660 "$1" "$2" "$3" "$4"
    chgrp "$5" "$1"
}
make_node /dev/video0 c 81 0 video
make_node /dev/ttyS0 c 4 64 dialout
make_node /dev/ttyUSB0 c 188 0 dialout
make_node /dev/ttyACM0 c 166 0 dialout
make_node /dev/jsar-blocked c 10 200 video
exec /sbin/init
