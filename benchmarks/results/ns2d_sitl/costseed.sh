#!/bin/bash
# arms of the ~11,000-cost point for one seed, in sequence (issue 29), resumable from their checkpoints:
#   bash benchmarks/results/ns2d_sitl/costseed.sh SEED ARM [ARM...]   (e.g. 2 sitl_unroll8; 2 sitl_unroll1 sitl_unroll1_noise)
S=$1; shift
cd /work/main
for A in "$@"; do
echo "=== start $(date) load $(cut -d' ' -f1-3 /proc/loadavg) arm $A seed $S"
nice -n 5 pdestream compare ns2d --modes solver-in-the-loop --set n=64 --set t_start=10 --set t_end=16 \
  --set n_frames=31 --coarse-n 32 --unroll 8 --noise 0.01 --steps 2200 --pairs-steps 11000 --test-samples 32 \
  --threads 1 --corrector-start zero --seeds 3 --only-seed $S --only-arm $A --out benchmarks/results/ns2d_sitl/c32_u8_cost11000
echo "=== end $(date) rc $?"
done
