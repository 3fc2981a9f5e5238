#!/bin/bash
# marginal wall per optimizer step of each arm ALONE on the machine (issue 29's cost model): steps 20..N from metrics.csv
# usage: benchmarks/results/ns2d_sitl/steprate.sh TAG [XLA_FLAGS value]   (stop 54: output in steprate.txt)
TAG=$1; export XLA_FLAGS="$2"
cd /work/main
O=/tmp/steprate_$TAG; rm -rf $O
for A in sitl_unroll8:60 sitl_unroll1:300; do
  ARM=${A%%:*}; N=${A##*:}
  if [ $ARM = sitl_unroll8 ]; then S="--steps $N --pairs-steps 300"; else S="--steps 60 --pairs-steps $N"; fi
  pdestream compare ns2d --modes solver-in-the-loop --set n=64 --set t_start=10 --set t_end=16 --set n_frames=31 \
    --coarse-n 32 --unroll 8 --noise 0.01 $S --test-samples 32 --threads 1 --corrector-start zero --seeds 1 \
    --only-arm $ARM --out $O > $O.$ARM.log 2>&1
  python - "$O/$ARM/metrics.csv" "$TAG" "$ARM" <<'PY'
import csv, sys
rows = list(csv.DictReader(open(sys.argv[1])))
a = next(r for r in rows if int(r["step"]) >= 20); b = rows[-1]
per = (float(b["elapsed"]) - float(a["elapsed"])) / (int(b["step"]) - int(a["step"]))
print(f"{sys.argv[2]} {sys.argv[3]}: {per:.3f} s per step (steps {a['step']}..{b['step']})")
PY
done
