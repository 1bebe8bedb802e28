#!/usr/bin/env bash
# A copy of another commit's cafe_mpc package under its own name (cafe_mpc_<commit>), importable next to this
# tree's, so that benchmarks/bench_update.py can replay both in one process, interleaved.
# Usage: benchmarks/make_baseline.sh COMMIT [DEST]   (DEST defaults to /tmp/cafe_mpc_baseline)
set -euo pipefail
commit=${1:?usage: make_baseline.sh COMMIT [DEST]}
dest=${2:-/tmp/cafe_mpc_baseline}
name=cafe_mpc_$(git rev-parse --short "$commit")
mkdir -p "$dest"
rm -rf "${dest:?}/$name"
tmp=$(mktemp -d)
git archive "$commit" src/cafe_mpc | tar -x -C "$tmp"
mv "$tmp/src/cafe_mpc" "$dest/$name"
rm -rf "$tmp"
grep -rl "cafe_mpc" "$dest/$name" --include='*.py' | xargs sed -i -E "s/\bcafe_mpc\b/$name/g"
echo "$dest/$name"
