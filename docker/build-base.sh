#!/usr/bin/env bash
# Make the Dockerfile's base image available and print its reference on stdout.
#
# Order: the image already present locally -> `docker pull` -> a python:3.11-slim-compatible
# stand-in built from Debian bookworm packages (debootstrap + `docker import`), for sites
# that cannot reach the public image registry. The stand-in is cached as
# undertow-base:bookworm and also tagged with the requested name, so that a plain
# `docker build .` finds it. Bookworm's python3 is 3.11, the version the project requires.
#
# Environment:
#   BASE_IMAGE     image the Dockerfile builds FROM (default python:3.11-slim)
#   LOCAL_BASE     name of the local stand-in (default undertow-base:bookworm)
#   DEBIAN_MIRROR  Debian mirror for debootstrap (default: from /etc/apt/sources.list*)
#   PULL_TIMEOUT   seconds allowed for the pull attempt (default 120)
# Progress goes to stderr; stdout carries only the image reference.
set -euo pipefail

BASE_IMAGE=${BASE_IMAGE:-python:3.11-slim}
LOCAL_BASE=${LOCAL_BASE:-undertow-base:bookworm}
PULL_TIMEOUT=${PULL_TIMEOUT:-120}
SUITE=bookworm
PACKAGES=python3,python3-venv,python3-pip,python-is-python3,ca-certificates

log() { printf 'build-base: %s\n' "$*" >&2; }

have_image() { docker image inspect "$1" >/dev/null 2>&1; }

# First http(s) URI configured for Debian's main suite, in deb822 or one-line form.
debian_mirror() {
  local f uri
  for f in /etc/apt/sources.list.d/*.sources; do
    [ -f "$f" ] || continue
    uri=$(awk -v suite="$SUITE" '
      BEGIN { RS = ""; FS = "\n" }
      {
        u = ""; ok = 0
        for (i = 1; i <= NF; i++) {
          if ($i ~ /^URIs:/)   { sub(/^URIs:[ \t]*/, "", $i); split($i, a, /[ \t]+/); u = a[1] }
          if ($i ~ /^Suites:/) { n = split($i, s, /[ \t]+/); for (j = 2; j <= n; j++) if (s[j] == suite) ok = 1 }
        }
        if (ok && u ~ /^https?:\/\//) { print u; exit }
      }' "$f")
    [ -n "$uri" ] && { echo "$uri"; return; }
  done
  for f in /etc/apt/sources.list /etc/apt/sources.list.d/*.list; do
    [ -f "$f" ] || continue
    uri=$(awk -v suite="$SUITE" '$1 == "deb" {
        for (i = 2; i <= NF; i++) if ($i !~ /^\[/ && $i !~ /\]$/) break
        if ($(i + 1) == suite && $i ~ /^https?:\/\//) { print $i; exit } }' "$f")
    [ -n "$uri" ] && { echo "$uri"; return; }
  done
  echo "http://deb.debian.org/debian"
}

build_local_base() {
  local mirror rootfs
  if ! command -v debootstrap >/dev/null 2>&1; then
    log "installing debootstrap"
    apt-get update -qq >&2
    DEBIAN_FRONTEND=noninteractive apt-get install -y -qq debootstrap >/dev/null
  fi
  mirror=${DEBIAN_MIRROR:-$(debian_mirror)}
  rootfs=$(mktemp -d /var/tmp/undertow-rootfs.XXXXXX)
  trap 'rm -rf "$rootfs"' EXIT
  log "debootstrap $SUITE (minbase + $PACKAGES) from $mirror"
  if ! debootstrap --variant=minbase --include="$PACKAGES" "$SUITE" "$rootfs" "$mirror" \
      >"$rootfs.log" 2>&1; then
    tail -30 "$rootfs.log" >&2
    log "debootstrap failed (full log: $rootfs.log)"
    return 1
  fi
  rm -f "$rootfs.log"
  # Keep the image small: package caches, indexes, manuals.
  rm -rf "$rootfs"/var/cache/apt/archives/*.deb "$rootfs"/var/cache/apt/*.bin \
    "$rootfs"/var/lib/apt/lists/* "$rootfs"/usr/share/man/* "$rootfs"/usr/share/info/* \
    "$rootfs"/var/log/*.log
  printf 'deb %s %s main\n' "$mirror" "$SUITE" >"$rootfs/etc/apt/sources.list"
  log "importing as $LOCAL_BASE"
  tar -C "$rootfs" -c . | docker import \
    --change 'ENV PATH=/usr/local/sbin:/usr/local/bin:/usr/sbin:/usr/bin:/sbin:/bin' \
    --change 'ENV LANG=C.UTF-8' \
    --change 'LABEL org.opencontainers.image.description="python:3.11-slim stand-in: Debian bookworm minbase with python3, built by undertow docker/build-base.sh"' \
    --change 'CMD ["python3"]' \
    - "$LOCAL_BASE" >/dev/null
  rm -rf "$rootfs"
  trap - EXIT
}

if have_image "$BASE_IMAGE"; then
  log "$BASE_IMAGE is present"
elif timeout "$PULL_TIMEOUT" docker pull "$BASE_IMAGE" >&2; then
  log "pulled $BASE_IMAGE"
else
  log "cannot pull $BASE_IMAGE; using the local stand-in $LOCAL_BASE"
  if have_image "$LOCAL_BASE"; then
    log "$LOCAL_BASE is cached"
  else
    build_local_base
  fi
  docker tag "$LOCAL_BASE" "$BASE_IMAGE"
  log "tagged $LOCAL_BASE as $BASE_IMAGE"
fi
echo "$BASE_IMAGE"
