#!/usr/bin/env bash
# Score a simulator's submission, compare it with a baseline result and gate on regressions.
#
#   run_gate.sh SUBMISSION BASELINE.json OUT_DIR SCENARIO_PATH...
#
# Writes OUT_DIR/new.json (the score), OUT_DIR/comparison.{txt,json,md}, OUT_DIR/report.html.
# Exit code: 0 scored and no gate failed (or no baseline yet), 1 a gate failed or the
# submission is invalid, 2 usage error (bad paths, results that cannot be compared).
#
# Settings (environment):
#   WOSAC_EVAL     the command to run (default: wosac-eval)
#   WOSAC_CONFIG   metrics config: 2025, 2024, 2023 or a .textproto (default: 2025)
#   WOSAC_GATES    space-separated METRIC:DELTA regressions to fail on
#                  (default: "metametric:0.005 simulated_collision_rate:0.01 simulated_offroad_rate:0.01")
#   WOSAC_WORKERS  scoring processes (default: 2)
#   WOSAC_SEED     seed of the comparison's bootstrap / permutation draws (default: 0)
set -uo pipefail

if [ "$#" -lt 4 ]; then
  echo "usage: $0 SUBMISSION BASELINE.json OUT_DIR SCENARIO_PATH..." >&2
  exit 2
fi
submission=$1 baseline=$2 out=$3
shift 3

read -r -a wosac_eval <<< "${WOSAC_EVAL:-wosac-eval}"
config=${WOSAC_CONFIG:-2025}
gates=${WOSAC_GATES:-"metametric:0.005 simulated_collision_rate:0.01 simulated_offroad_rate:0.01"}
workers=${WOSAC_WORKERS:-2}
seed=${WOSAC_SEED:-0}

mkdir -p "$out" || exit 2

"${wosac_eval[@]}" score --scenarios "$@" --submission "$submission" --config "$config" \
  --workers "$workers" --output "$out/new.json"
status=$?
if [ "$status" -ne 0 ]; then
  echo "run_gate: scoring failed (exit $status)" >&2
  exit "$status"
fi

summary() {  # append to the GitHub Actions job summary when running there
  if [ -n "${GITHUB_STEP_SUMMARY:-}" ]; then cat >> "$GITHUB_STEP_SUMMARY"; else cat > /dev/null; fi
}

if [ ! -f "$baseline" ]; then
  echo "run_gate: no baseline at $baseline; nothing to compare (commit $out/new.json there to start gating)"
  "${wosac_eval[@]}" report "$out/new.json" --html "$out/report.html"
  printf '### WOSAC realism\nNo baseline yet; see the report artifact.\n' | summary
  exit 0
fi

gate_args=()
for gate in $gates; do gate_args+=(--fail-if-worse "$gate"); done

"${wosac_eval[@]}" compare "$baseline" "$out/new.json" "${gate_args[@]}" --seed "$seed" \
  --json-output "$out/comparison.json" --markdown-output "$out/comparison.md" | tee "$out/comparison.txt"
status=${PIPESTATUS[0]}

# The report is written whatever the gate said: it is what a reviewer opens when it failed.
"${wosac_eval[@]}" report "$out/new.json" --compare "$baseline" --seed "$seed" --html "$out/report.html" \
  || echo "run_gate: the report could not be written" >&2

if [ -f "$out/comparison.md" ]; then summary < "$out/comparison.md"; fi

case "$status" in
  0) echo "run_gate: all gates passed" ;;
  1) echo "run_gate: a regression gate failed (see $out/comparison.txt and $out/report.html)" >&2 ;;
  *) echo "run_gate: the results could not be compared (exit $status)" >&2 ;;
esac
exit "$status"
