#!/usr/bin/env bash
# Rebuild the README's figures: one `piest` run per capability, on the shipped data where there is
# measured data to use. Run from the repository root with the package installed:
#     bash docs/figures/make_figures.sh
set -euo pipefail
cd "$(dirname "$0")"
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
data() { python -c "import piest_jax as pj; print(pj.dataset_path('$1'))"; }
AYE_ID=$(data piezo_aye2018_identification.csv)
AYE_VAL=$(data piezo_aye2018_validation.csv)

piest simulate --out "$work/sim" --quiet
piest reproduce fig5 --out "$work/paper" --quiet
piest montecarlo --inputs 2100 --samples 2000 --plays 6 --seed 0 --out "$work/pe-map" --quiet
piest excite --thresholds 0,3.3333,6.6667 --amplitude 10 --samples 5000 --out "$work/excite" --quiet
piest fit "$AYE_ID" --plays auto --validate "$AYE_VAL" --out "$work/fitted" --quiet
# The output the actuator produced on the validation run (its `desired` column is in another frame).
piest compensate "$work/fitted/fit.json" "$AYE_VAL" --column y --out "$work/ff" --quiet
piest diagnose "$AYE_ID" --validate "$AYE_VAL" --out "$work/diag" --quiet

cp "$work/sim/loop.png" simulate.png
cp "$work/paper/fig5.png" reproduce_fig5.png
cp "$work/pe-map/pe_map.png" montecarlo_pe_map.png
cp "$work/excite/excite.png" excite.png
cp "$work/fitted/validation.png" fit_validation.png
cp "$work/ff/compensate.png" compensate.png
cp "$work/diag/report.png" diagnose.png
chmod 644 ./*.png
ls -l ./*.png
