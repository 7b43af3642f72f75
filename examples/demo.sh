#!/usr/bin/env bash
# The whole pipeline on the bundled phantom recording (made by `vfcli synth`).
# Runs every stage that exists, in order, and says plainly which stages are still missing
# or were skipped because a stage they need is missing. Never fakes a stage.
# usage: examples/demo.sh [OUTDIR]      (make demo runs it with OUTDIR=demo)
# EFFECT=random SEED=3 make demo   hides a physics effect in the phantom (named only in truth.h5)
set -u
OUT=${1:-demo}
VF=${VFCLI:-.venv/bin/vfcli}
RAW="$OUT/raw"
STORE="$OUT/recording.h5"
mkdir -p "$OUT"
declare -A STATE   # stage -> done | missing | skipped

step() {  # step NAME "NEEDS" ARGS...
    local name=$1 needs=$2; shift 2
    for n in $needs; do
        if [ "${STATE[$n]:-}" != done ]; then
            STATE[$name]=skipped
            echo "-- vfcli $name: skipped (needs '$n', which is ${STATE[$n]:-not run})"
            return
        fi
    done
    echo "== vfcli $name $*"
    "$VF" "$name" "$@"
    local rc=$?
    case $rc in
        0) STATE[$name]=done ;;
        6) STATE[$name]=missing ;;
        *) echo "demo: vfcli $name failed with exit code $rc" >&2; exit $rc ;;
    esac
}

step synth      ""                "$RAW" --seed "${SEED:-1}" --effect "${EFFECT:-none}"
step ingest-hsc "synth"           "$STORE" "$RAW/video.cihx" --pressure "$RAW/video_pressure.tdms" --config "$RAW/recording.toml"
step ingest-ldv "synth"           "$STORE" "$RAW/scan.uff"
step sync       "ingest-hsc ingest-ldv" "$STORE"
step flow       "sync"            "$STORE"
step mesh       ""                "$STORE" --preview "$OUT/mesh.png"
step optimize   "flow mesh"       "$STORE" --plot "$OUT/convergence.png" --uncertainty-map "$OUT/inferior_uncertainty.png"
step export     "optimize"        "$STORE" --to "$OUT/export"
step report     "ingest-hsc"      "$STORE" --out "$OUT/report.html"

echo
echo "== results"
for s in synth ingest-hsc ingest-ldv sync flow mesh optimize export report; do
    printf '  %-11s %s\n' "$s" "${STATE[$s]:-not run}"
done
if [ -f "$STORE" ]; then
    echo
    "$VF" info "$STORE"
    echo
    echo "Results: store $STORE (open it with HDFView or h5dump)"
    for f in "$OUT"/*.png; do [ -e "$f" ] && echo "         picture $f"; done
    [ -d "$OUT/export/paraview" ] && echo "         ParaView: $OUT/export/paraview/*.vtkhdf (or *.pvd), video $OUT/export/video/overlay.mp4"
    [ -f "$OUT/report.html" ] && echo "         report  $OUT/report.html (open it in a browser)"
fi
missing=$(for s in "${!STATE[@]}"; do [ "${STATE[$s]}" != done ] && echo "$s"; done | sort | tr '\n' ' ')
[ -n "$missing" ] && echo "Not yet available in this version: $missing(see README, 'Status')"
exit 0
