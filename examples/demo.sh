#!/usr/bin/env bash
# The whole pipeline on the bundled phantom recording (made by `vfcli synth`).
# `vfcli run` runs every stage that is not up to date, in one process, then writes the export
# folder; it would end with the diagnosis too, but the demo stops it at optimize and runs
# `vfcli diagnose` by itself to draw the residual map (--map): it locates where the fit and the
# recording disagree and names the missing physics; `vfcli report` writes the HTML report;
# `vfcli mesh --preview` draws the (up-to-date) mesh. Rerunning the demo does only what changed. Never fakes a stage: a failing
# step stops the demo with its code.
# usage: examples/demo.sh [OUTDIR]      (make demo runs it with OUTDIR=demo)
# EFFECT=random SEED=3 make demo   hides a physics effect in the phantom (named only in truth.h5)
set -u
OUT=${1:-demo}
VF=${VFCLI:-.venv/bin/vfcli}
RAW="$OUT/raw"
STORE="$OUT/recording.h5"
mkdir -p "$OUT"

step() {  # step COMMAND ARGS...
    echo "== vfcli $*"
    "$VF" "$@"
    local rc=$?
    if [ $rc != 0 ]; then
        echo "demo: vfcli $1 failed with exit code $rc" >&2
        exit $rc
    fi
}

step synth "$RAW" --seed "${SEED:-1}" --effect "${EFFECT:-none}"
step run "$STORE" --raw "$RAW" --until optimize --export "$OUT/export"
step diagnose "$STORE" --run default --map "$OUT/residual_map.png"
step report "$STORE" --out "$OUT/report.html"
step mesh "$STORE" --preview "$OUT/mesh.png"

echo
"$VF" info "$STORE"
echo
echo "Results: store $STORE with its folder $STORE.parts/ (open it with HDFView or h5dump)"
for f in "$OUT"/*.png "$OUT"/export/figures/*.png; do [ -e "$f" ] && echo "         picture $f"; done
[ -d "$OUT/export/paraview" ] && echo "         ParaView: $OUT/export/paraview/*.vtkhdf (or *.pvd), video $OUT/export/video/overlay.mp4"
[ -f "$OUT/report.html" ] && echo "         report  $OUT/report.html (open it in a browser)"
exit 0
