#!/bin/sh
# tests/pythons.py on Debian sid's Python 3.14, for a machine whose pyenv has no 3.14 (and cannot
# download one): sid, with python3.14, its headers, gcc and Mesa's EGL (MuJoCo's renderer), is
# bootstrapped once into $SID (default /var/tmp/episode-audit-sid); this repository is mounted
# there at the same path, and the suite runs in .venv-3.14 with the newest releases.
# Needs root and debootstrap (apt-get install debootstrap). About 1 minute to bootstrap, then
# as long as one leg of `make test-pythons`.
#
#     sh tests/sid.sh            # PY=python3.14 SID=/var/tmp/episode-audit-sid
set -eu
REPO=$(cd "$(dirname "$0")/.." && pwd)
SID=${SID:-/var/tmp/episode-audit-sid}
PY=${PY:-python3.14}
if [ ! -x "$SID/usr/bin/$PY" ]; then
    debootstrap --variant=minbase \
        --include="$PY,$PY-venv,$PY-dev,gcc,libc6-dev,git,ca-certificates,libegl1,libegl-mesa0,libgl1,libglx-mesa0,libgles2" \
        sid "$SID" http://deb.debian.org/debian
fi
# The host's certificates (pip behind a proxy that re-signs), for pip and uv in the chroot.
CERT=${PIP_CERT:-/etc/ssl/certs/ca-certificates.crt}
cp "$CERT" "$SID/etc/ssl/certs/host-ca.crt"
mkdir -p "$SID$REPO"
cleanup() {
    umount "$SID$REPO" "$SID/dev" "$SID/proc" 2>/dev/null || true
}
trap cleanup EXIT INT TERM
mount -t proc proc "$SID/proc"
mount --bind /dev "$SID/dev"
mount --bind "$REPO" "$SID$REPO"
chroot "$SID" /usr/bin/env -i HOME=/root PATH=/usr/bin:/bin TMPDIR=/tmp \
    PIP_CERT=/etc/ssl/certs/host-ca.crt SSL_CERT_FILE=/etc/ssl/certs/host-ca.crt \
    PIP_DISABLE_PIP_VERSION_CHECK=1 PIP_DEFAULT_TIMEOUT=180 \
    sh -c "cd '$REPO' && git config --global --add safe.directory '$REPO' && $PY tests/pythons.py /usr/bin/$PY"
