#!/usr/bin/env bash
# Container smoke test: build the image, then run brl through `docker run` as a non-root uid with a read-only root
# filesystem: preview, a 300-step train, a 10 % paper-suite bench, and one bad input (one line, exit 2).
# Needs a Docker engine. Not part of the default test suite.
#
#   scripts/docker-smoke.sh [IMAGE_TAG [DOCKER_BUILD_ARGS...]]
#   e.g. scripts/docker-smoke.sh brl:smoke --build-arg TORCH_INDEX= --build-arg EXTRA_CA_CERTS="$(cat ca.pem)"
#
# Environment: KEEP_OUT=1 keeps the output directory.
set -euo pipefail
cd "$(dirname "$0")/.."
tag=${1:-brl:smoke}
shift $(( $# > 0 ? 1 : 0 ))
out=$(mktemp -d "${TMPDIR:-/tmp}/brl-smoke.XXXXXX")
chmod 777 "$out"  # the container writes as another uid than the caller
trap '[ "${KEEP_OUT:-0}" = 1 ] || rm -rf "$out"' EXIT
fail() { echo "smoke: FAIL: $*" >&2; exit 1; }

t0=$(date +%s)
docker build -q "$@" --build-arg GIT_COMMIT="$(git rev-parse HEAD 2>/dev/null || echo unknown)" -t "$tag" . >/dev/null
echo "smoke: built $tag in $(( $(date +%s) - t0 )) s, $(docker image inspect "$tag" --format '{{.Size}}' | awk '{printf "%.2f GB", $1/1e9}')"

run() {  # non-root uid, read-only root filesystem, a tmpfs for /tmp, the output directory mounted
    docker run --rm --user 4321:4321 --read-only --tmpfs /tmp:rw,exec,size=1g --shm-size=512m \
        -v "$out:/work/out" "$tag" "$@"
}

run preview town02 --weathers 1 --out /work/out/preview >/dev/null
[ -s "$out/preview/town02_topdown.png" ] || fail "preview wrote no picture"
grep -q '"git_commit": "'"$(git rev-parse HEAD 2>/dev/null || echo unknown)"'"' "$out/preview/run.json" \
    || fail "run.json does not record the build's git commit"
echo "smoke: preview ok"

run train --steps 300 --no-evaluate --out /work/out/train >/dev/null
[ -s "$out/train/seed_0/model.npz" ] || fail "train wrote no model"
echo "smoke: train ok"

run bench --suite paper --model /work/out/train/seed_0 --episodes 0.1 --out /work/out/bench >/dev/null
[ "$(wc -l < "$out/bench/results.jsonl")" -ge 6 ] || fail "bench wrote fewer than 6 episodes"
echo "smoke: bench ok ($(wc -l < "$out/bench/results.jsonl") episodes)"

set +e
err=$(run train --steps abc --out /work/out/bad 2>&1 >/dev/null)
code=$?
set -e
[ "$code" = 2 ] || fail "bad input exited with $code, not 2"
[ "$(printf '%s\n' "$err" | wc -l)" = 1 ] && [[ "$err" == "brl: error:"* ]] || fail "bad input printed: $err"
[ ! -e "$out/bad" ] || fail "bad input wrote $out/bad"
echo "smoke: bad input ok ($err)"
echo "smoke: PASS in $(( $(date +%s) - t0 )) s"
