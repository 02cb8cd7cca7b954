#!/usr/bin/env bash
# The paper's generalization tables (issue 34): LIBERO-10 and the five derived suites, the learned
# policies with and without steering, all into one results database, then `seal report` on it
# (Table II layout for libero_10, Table VII for the language and visual suites, Table VIII for
# composition).
#
#   scripts/generalization.sh              run (or continue) everything, then write the report
#   scripts/generalization.sh --plan       trials and estimated CPU hours as JSON (nothing runs)
#   scripts/generalization.sh --dry-run    the `seal eval` commands it would run, one per line
#
# Environment:
#   DB           results database (default: ../runs/eval/generalization.db beside the checkout);
#                logs go to <DB without .db>_logs/, traces to <DB without .db>_runs/
#   TRIALS       trials per task on libero_10 and the language/visual suites (default 3)
#   COMP_TRIALS  trials per task on composition (default 5)
#   SUITES       comma-separated subset of the six suites (default: all)
#   TASKS        comma-separated task ids, in every suite run (default: all)
#   METHODS      comma-separated subset of twin,twin_vgps,vla,vla_seal,vla_seal_learned (default: all)
#   VALUE_CKPT   twin + V-GPS's Q-function: a `seal train value` run directory or a shipped name
#                (unset: the package's shipped one; one that does not load stops the script before a trial)
#   LEARNED_THRESHOLD  the learned verifier's operating point for vla_seal_learned (unset: the checkpoint's;
#                set, the method is another configuration, named with its threshold)
#   MAX_STEPS    episode cap (--max-steps), for smoke tests only: it is not part of a method's
#                identity, so capped trials would pass for real ones; refused with the default DB
#   WORKERS      trials run in parallel (seal eval --workers, default 1); one per free core
#   RETRY_ERRORS set to 1: also run again the trials stored as errors (seal eval --retry-errors)
#   SEAL         the seal executable (default: this checkout's .venv/bin/seal)
#   REPORT_ARGS  extra `seal report` options (default: --media link)
#
# Every trial is stored the moment it finishes and `seal eval` skips stored trials, so running the
# script again with the same settings continues where it stopped. Trial t of a task gets the same
# init state and seed under every method, so the tables pair the methods start by start.
set -euo pipefail

here="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
root="$(cd "$here/.." && pwd)"
SEAL="${SEAL:-$root/.venv/bin/seal}"
# the interpreter beside the seal executable checks the method strings and makes the plan
PYTHON="$(dirname "$SEAL")/python"
[ -x "$PYTHON" ] || PYTHON="$root/.venv/bin/python"

default_db="$(realpath -m "$root/../runs/eval/generalization.db")"
DB="$(realpath -m "${DB:-$default_db}")"  # absolute, so a later cd, the logs and the report agree on it
TRIALS="${TRIALS:-3}"
COMP_TRIALS="${COMP_TRIALS:-5}"
ALL_SUITES="libero_10,lang_rephrase,lang_object_property,visual_scene,visual_viewpoint,composition"
SUITES="${SUITES:-$ALL_SUITES}"
TASKS="${TASKS:-}"
MAX_STEPS="${MAX_STEPS:-}"
VALUE_CKPT="${VALUE_CKPT:-}"
REPORT_ARGS="${REPORT_ARGS:---media link}"
RETRY_ERRORS="${RETRY_ERRORS:-}"
WORKERS="${WORKERS:-1}"

# Methods in table order (scripts/generalization_plan.py holds the same table and the cost
# estimates). One `seal eval` per suite takes every method, and it runs a start under each method
# before the next start: a run stopped at any point has rows paired start by start, not all of the
# cheap methods and none of the steered ones.
ORDER=(twin twin_vgps vla vla_seal vla_seal_learned)
declare -A ITEM=(
  [twin]="base:policy=vla:policy_ckpt=twin"
  [twin_vgps]="value:policy=vla:policy_ckpt=twin${VALUE_CKPT:+:value_ckpt=$VALUE_CKPT}:k=10"
  [vla]="base:policy=vla"
  [vla_seal]="seal:policy=vla:k=10"
  [vla_seal_learned]="seal:policy=vla:k=10:verifier=learned${LEARNED_THRESHOLD:+:threshold=$LEARNED_THRESHOLD}"
)
declare -A NAME=(
  [twin]="twin (pi0)"
  [twin_vgps]="twin + V-GPS"
  [vla]="reasoning VLA"
  [vla_seal]="reasoning VLA + SEAL (oracle)"
  [vla_seal_learned]="reasoning VLA + SEAL (learned verifier${LEARNED_THRESHOLD:+, threshold $LEARNED_THRESHOLD})"
)
METHODS="${METHODS:-$(IFS=,; echo "${ORDER[*]}")}"

die() { echo "generalization.sh: $*" >&2; exit 2; }

mode=run
case "${1:-}" in
  "") ;;
  --plan) mode=plan ;;
  --dry-run) mode=dry ;;
  -h|--help) sed -n '2,/^set -euo/p' "$0" | sed '$d; s/^# \{0,1\}//'; exit 0 ;;
  *) die "unknown argument '$1' (use --plan, --dry-run or nothing)" ;;
esac

# ---- what to run ------------------------------------------------------------------------------
IFS=, read -r -a want_methods <<< "$METHODS"
for m in "${want_methods[@]}"; do
  [ -n "${ITEM[$m]+x}" ] || die "unknown method '$m' in METHODS; valid: ${ORDER[*]}"
done
IFS=, read -r -a want_suites <<< "$SUITES"
for s in "${want_suites[@]}"; do
  [[ ",$ALL_SUITES," == *",$s,"* ]] || die "unknown suite '$s' in SUITES; valid: $ALL_SUITES"
done
for n in "$TRIALS" "$COMP_TRIALS" "$WORKERS" ${MAX_STEPS:+"$MAX_STEPS"}; do
  [[ "$n" =~ ^[1-9][0-9]*$ ]] || die "TRIALS, COMP_TRIALS, WORKERS and MAX_STEPS must be positive integers (got '$n')"
done

wanted() { [[ ",$METHODS," == *",$1,"* ]]; }
methods=()
for m in "${ORDER[@]}"; do
  wanted "$m" || continue
  methods+=("$m")
done

if [ "$mode" = plan ]; then
  costs=()
  [ -f "$DB" ] && costs=(--costs "$DB")
  exec "$PYTHON" "$here/generalization_plan.py" "${costs[@]}" --suites "$SUITES" --methods "$METHODS" \
    --tasks "$TASKS" --trials "$TRIALS" --comp-trials "$COMP_TRIALS" ${MAX_STEPS:+--max-steps "$MAX_STEPS"} \
    ${VALUE_CKPT:+--value-ckpt "$VALUE_CKPT"}
fi

[ ${#methods[@]} -gt 0 ] || die "no method left to run (METHODS=$METHODS)"
if [ -n "$MAX_STEPS" ] && [ "$DB" = "$default_db" ]; then
  die "MAX_STEPS caps episodes without changing the methods' identity: set DB to a scratch database"
fi

trials_of() { if [ "$1" = composition ]; then echo "$COMP_TRIALS"; else echo "$TRIALS"; fi; }
command_for() {  # the seal eval command of one suite and every method, as arguments
  local suite="$1" items=() m
  for m in "${methods[@]}"; do items+=("${ITEM[$m]}"); done
  cmd=("$SEAL" eval --suite "$suite" --methods "$(IFS=,; echo "${items[*]}")" --trials "$(trials_of "$suite")" --db "$DB"
       --render fast --workers "$WORKERS" --video none)
  [ -n "$TASKS" ] && cmd+=(--tasks "$TASKS")
  [ -n "$MAX_STEPS" ] && cmd+=(--max-steps "$MAX_STEPS")
  [ "$RETRY_ERRORS" = 1 ] && cmd+=(--retry-errors)
  return 0
}

if [ "$mode" = dry ]; then
  for s in ${ALL_SUITES//,/ }; do
    [[ ",$SUITES," == *",$s,"* ]] || continue
    command_for "$s"
    printf '%s\n' "${cmd[*]}"
  done
  exit 0
fi

# Every method string must parse (a V-GPS directory without weights, a typo) before the first trial
# runs, rather than after hours of the cheaper methods.
items=()
for m in "${methods[@]}"; do items+=("${ITEM[$m]}"); done
"$PYTHON" - "${items[@]}" <<'EOF' || die "a method string did not parse (see above)"
import sys
from seal.errors import InvalidInput
from seal.steer.method import parse_methods
try:
    for item in sys.argv[1:]:
        parse_methods(item, render="fast")
except InvalidInput as exc:
    sys.exit(f"generalization.sh: {exc}")
EOF

# ---- run ----------------------------------------------------------------------------------------
mkdir -p "$(dirname "$DB")"
logs="${DB%.db}_logs"
mkdir -p "$logs"
echo "generalization.sh: database $DB, logs in $logs"

for s in ${ALL_SUITES//,/ }; do
  [[ ",$SUITES," == *",$s,"* ]] || continue
  command_for "$s"
  log="$logs/$s.log"
  names=()
  for m in "${methods[@]}"; do names+=("${NAME[$m]}"); done
  echo "generalization.sh: $s, $(IFS=';'; echo "${names[*]}" | sed 's/;/; /g') ($(trials_of "$s") trials per task) -> $log"
  { echo "=== $(date -u +%Y-%m-%dT%H:%M:%SZ) ${cmd[*]}"; } >> "$log"
  # the log keeps every attempt, appended; seal eval's last stdout line is its JSON summary
  "${cmd[@]}" 2>&1 | tee -a "$log"
done

report_log="$logs/report.log"
echo "generalization.sh: seal report -> $report_log"
# shellcheck disable=SC2086  # REPORT_ARGS is a list of options
"$SEAL" report "$DB" $REPORT_ARGS 2>&1 | tee -a "$report_log"
echo "generalization.sh: done; report in ${DB%.db}_report/ unless REPORT_ARGS set --out"
