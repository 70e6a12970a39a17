#!/usr/bin/env bash
# make-base.sh - provide the bench's base image (make base).
#
# Usage: make-base.sh <base-image> <output-tag> [ca-bundle]
#   1. use <base-image> if Docker has it (or the debootstrap image made here earlier
#      because it could not be pulled), else try `docker pull` (bounded);
#   2. if that fails (no registry), build an equivalent image from Debian
#      packages with debootstrap (bookworm, minbase) and `docker import` it;
#   3. either way, tag <output-tag> = that image plus the CA bundle (default:
#      the host's, or BENCH_CA_BUNDLE) so pip, cargo and apt inside image
#      builds trust the same TLS-intercepting proxy the host does.
# Prints which path was taken. debootstrap (installed by scripts/host-deps when missing)
# runs as root: directly, or through passwordless sudo.
set -euo pipefail

base=$1
out=$2
ca=${3:-${BENCH_CA_BUNDLE:-/etc/ssl/certs/ca-certificates.crt}}
here=$(cd "$(dirname "$0")" && pwd)
work=${BUILD_DIR:-build}/base
suite=${DEBIAN_SUITE:-bookworm}
mirror=${DEBIAN_MIRROR:-http://deb.debian.org/debian}
local_base=canbench/debootstrap:$suite

if docker image inspect "$base" >/dev/null 2>&1; then
	echo "base: using $base (already present)"
	from=$base
elif docker image inspect "$local_base" >/dev/null 2>&1; then
	# made here before, because $base could not be pulled then: not tried again on every run
	echo "base: using $local_base built earlier from Debian packages ($base could not be pulled)"
	from=$local_base
elif timeout 120 docker pull "$base" >/dev/null 2>&1; then
	echo "base: pulled $base"
	from=$base
else
	echo "base: $base cannot be pulled; building $local_base from Debian packages with debootstrap"
	# debootstrap installs itself when it can (root or passwordless sudo), else names the command
	"$here/../../scripts/host-deps" "make base (no $base to pull)" debootstrap
	# the root file system is root's: debootstrap, tar and rm run as root
	if [ "$(id -u)" = 0 ]; then
		as_root=()
	elif sudo -n true 2>/dev/null; then
		as_root=(sudo -n)
	else
		echo "base: debootstrap needs root: run once: sudo make base (or make debian:bookworm-slim pullable)" >&2
		exit 1
	fi
	"${as_root[@]}" rm -rf "$work/rootfs"
	mkdir -p "$work"
	"${as_root[@]}" debootstrap --variant=minbase --include=ca-certificates "$suite" "$work/rootfs" "$mirror" \
		>"$work/debootstrap.log" 2>&1 || { tail -n 20 "$work/debootstrap.log" >&2; exit 1; }
	# the same sources as debian:bookworm-slim: main, updates, security (rustc-web lives there)
	"${as_root[@]}" tee "$work/rootfs/etc/apt/sources.list" >/dev/null <<SOURCES
deb $mirror $suite main
deb $mirror $suite-updates main
deb http://deb.debian.org/debian-security $suite-security main
SOURCES
	"${as_root[@]}" sh -c 'rm -rf "$1/var/cache/apt/archives/"*.deb "$1/var/lib/apt/lists/"*' sh "$work/rootfs"
	"${as_root[@]}" tar -C "$work/rootfs" -c . | docker import \
		--change 'ENV LANG=C.UTF-8 PATH=/usr/local/sbin:/usr/local/bin:/usr/sbin:/usr/bin:/sbin:/bin' \
		--change 'CMD ["bash"]' - "$local_base" >/dev/null
	"${as_root[@]}" rm -rf "$work/rootfs"
	from=$local_base
fi

[ -r "$ca" ] || { echo "base: CA bundle $ca is not readable (set BENCH_CA_BUNDLE)" >&2; exit 1; }
# what $out is made of, recorded when it was made: unchanged, it is not built again (a warm
# make test saves the build's seconds; the image, and so every image's layer cache, stays)
inputs="$(docker image inspect -f '{{.Id}}' "$from") $(cat "$ca" "$here/Dockerfile" | sha256sum | cut -c1-16)"
stamp=$work/inputs
if [ -f "$stamp" ] && [ "$(cat "$stamp")" = "$inputs $(docker image inspect -f '{{.Id}}' "$out" 2>/dev/null)" ]; then
	echo "base: $out up to date ($from + CA bundle from $ca)"
	exit 0
fi
ctx=$(mktemp -d)
trap 'rm -rf "$ctx"' EXIT
cp "$ca" "$ctx/bench-ca-bundle.pem"
cp "$here/Dockerfile" "$ctx/"
docker build -q --build-arg FROM_IMAGE="$from" -t "$out" "$ctx" >/dev/null 2>"$ctx/build.err" ||
	{ cat "$ctx/build.err" >&2; exit 1; }
mkdir -p "$work"
echo "$inputs $(docker image inspect -f '{{.Id}}' "$out")" >"$stamp"
echo "base: $out = $from + CA bundle from $ca"
