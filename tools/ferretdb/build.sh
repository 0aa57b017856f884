#!/usr/bin/env bash
# Builds FerretDB (MongoDB's wire protocol over SQLite) from the Go module proxy, at the
# version pinned in tools/ferretdb/go.mod, unless the binary is already there.
#
#   tools/ferretdb/build.sh [OUTPUT]     default OUTPUT: .cache/ferretdb/<version>/bin/ferretdb
#
# The module zip has no build/version/version.txt (FerretDB's own build generates it) and
# the binary panics at start without one, so the module is vendored in a scratch folder,
# version.txt is written there, and the binary is built from the vendored copy.
# Needs Go >= 1.24 and the module proxy (or a module cache that holds the modules).
# Prints one line on success; on failure, says why on stderr and exits non-zero.
set -euo pipefail

here="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
root="$(cd "$here/../.." && pwd)"

fail() {
  echo "tools/ferretdb/build.sh: FAILED: $*" >&2
  exit 1
}

version="$(awk '$1 == "github.com/FerretDB/FerretDB" { print $2 }' "$here/go.mod")"
[ -n "$version" ] || fail "no github.com/FerretDB/FerretDB version in $here/go.mod"

out="${1:-$root/.cache/ferretdb/$version/bin/ferretdb}"
case "$out" in /*) ;; *) out="$PWD/$out" ;; esac

if [ -x "$out" ]; then
  echo "ferretdb $version: already built at $out"
  exit 0
fi

command -v go >/dev/null 2>&1 \
  || fail "'go' is not on PATH; FerretDB $version is built from source and needs Go >= 1.24"

mkdir -p "$(dirname "$out")"
scratch="$(mktemp -d "$(dirname "$out")/.build.XXXXXX")"
trap 'rm -rf "$scratch"' EXIT
log="$scratch/build.log"

step() {  # step DESCRIPTION COMMAND...: runs it with its output in the log; the log on failure
  local what="$1"
  shift
  if ! "$@" >>"$log" 2>&1; then
    tail -n 40 "$log" >&2
    fail "$what (go: $(go version 2>/dev/null || echo unknown))"
  fi
}

started=$SECONDS
cp "$here/go.mod" "$here/go.sum" "$scratch/"
cd "$scratch"
# Flags given here, not inherited: a GOFLAGS=-mod=... of the caller must not change the build.
export GOFLAGS="" CGO_ENABLED=0
step "go mod vendor (downloads FerretDB $version and its modules)" go mod vendor
printf '%s\n' "$version" >vendor/github.com/FerretDB/FerretDB/build/version/version.txt
step "go build of github.com/FerretDB/FerretDB/cmd/ferretdb" \
  go build -mod=vendor -trimpath -buildvcs=false -o "$scratch/ferretdb" \
  github.com/FerretDB/FerretDB/cmd/ferretdb
step "the built binary does not run (ferretdb --version)" "$scratch/ferretdb" --version
mv -f "$scratch/ferretdb" "$out"  # same folder tree: an atomic rename

echo "ferretdb $version: built in $((SECONDS - started)) s at $out"
