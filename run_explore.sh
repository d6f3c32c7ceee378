#!/usr/bin/env bash
B=/work/main/.venv/bin/babblegen
cd /work/data45
run() { # name seed attempts args...
  local out=$1 seed=$2 n=$3; shift 3
  [ -f $out/done ] && return
  rm -rf $out
  /usr/bin/time -f "%e s" -o $out.time $B generate --out $out --seed $seed --max-attempts $n --workers 2 --no-rerun --no-progress "$@" > $out.log 2>&1 && touch $out/done
}
run nv_varied1 1 1200 --objects varied
run rw_varied1 1 1200 --explorer random_waypoints --objects varied
run test_heldout_rw 101 400 --explorer random_waypoints --objects heldout
run test_heldout_nv 101 400 --objects heldout
run test_varied_rw 102 400 --explorer random_waypoints --objects varied
run test_paper_rw 103 400 --explorer random_waypoints --objects paper
for s in 2 3; do
  run nv_varied$s $s 1200 --objects varied
  run rw_varied$s $s 1200 --explorer random_waypoints --objects varied
  run nv_paper$s $s 1200 --objects paper
done
