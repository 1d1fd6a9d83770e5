#!/bin/busybox sh
# /init of the test VM (see run_v4l2_vm_test.sh): load v4l2loopback the way users do
# (exclusive_caps=1), mount the host's root read-only and the exchange folder over its /tmp (the
# host's /tmp stays reachable as /tmp/.host-tmp),
# run /tmp/guest.sh in a chroot of the host, then power off.
/bin/busybox --install -s /bin
mount -t proc proc /proc
mount -t sysfs sysfs /sys
mount -t devtmpfs devtmpfs /dev

for name in mc videodev virtio_ring virtio virtio_pci_legacy_dev virtio_pci_modern_dev virtio_pci \
            9pnet 9pnet_virtio netfs fscache 9p; do
  insmod /modules/$name.ko || echo "init: insmod $name failed"
done
# /dev/video0 with the label users see (packaging/modprobe.conf), and /dev/video1, a second
# loopback device that plays the target's camera (fed by a writer the guest script kills and
# restarts: unplug and replug). The kernel keeps spaces only inside one pair of quotes around the
# whole list, so the labels are listed in one string, in video_nr's order.
insmod /modules/v4l2loopback.ko devices=2 video_nr=1,0 exclusive_caps=1,1 \
  'card_label="Test Camera,Face Reenact"' || echo "init: insmod v4l2loopback failed"
# The loopback network interface, for the browser check's page on http://127.0.0.1.
ip link set lo up || echo "init: bringing up lo failed"
# netem, the kernel's network emulator: the expression stream's loss, duplication and reordering.
insmod /modules/sch_netem.ko || echo "init: insmod sch_netem failed"

mount -t 9p -o trans=virtio,version=9p2000.L,ro,cache=loose,msize=524288 host /host || echo "init: mounting host root failed"
# The exchange folder hides the host's own /tmp; keep that reachable as /tmp/.host-tmp inside the
# chroot, so a checkout or build under /tmp still works (run_v4l2_vm_test.sh maps the paths).
mkdir -p /host-tmp && mount -o bind /host/tmp /host-tmp || echo "init: keeping the host's /tmp failed"
mount -t 9p -o trans=virtio,version=9p2000.L,rw,msize=524288 exchange /host/tmp || echo "init: mounting exchange failed"
mkdir -p /host/tmp/.host-tmp && mount -o bind /host-tmp /host/tmp/.host-tmp || echo "init: binding the host's /tmp failed"
mount -t devtmpfs devtmpfs /host/dev
mount -t proc proc /host/proc
mount -t sysfs sysfs /host/sys
mount -t tmpfs tmpfs /host/run 2>/dev/null
mkdir -p /host/dev/shm && mount -t tmpfs tmpfs /host/dev/shm 2>/dev/null  # Chromium's shared memory

chroot /host /bin/bash /tmp/guest.sh >/host/tmp/guest.log 2>&1
echo $? >/host/tmp/guest.status
sync
umount /host/tmp/.host-tmp
umount /host/tmp
poweroff -f
