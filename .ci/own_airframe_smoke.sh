#!/usr/bin/env bash
# Smoke test of a user's own airframe through every command, as a user meets it: the installed
# `uavdyn` (a wheel, not the source tree), run from an empty folder on the repository's two
# example airframes (examples/trainer.toml, examples/x500.toml). Small sizes: this checks that
# each command runs and writes what it says on an airframe the project does not ship, not the
# accuracy (the tests and the validation report do that).
#   usage: own_airframe_smoke.sh UAVDYN_EXECUTABLE EXAMPLES_DIR
set -euo pipefail
UAVDYN=$1
EXAMPLES=$(cd "$2" && pwd)
START=$SECONDS

step() {  # step NAME COMMAND...: run, time, and on failure show the command's last lines
    local name=$1; shift
    local t0=$SECONDS
    if ! "$@" > "$name.log" 2>&1; then
        echo "own-airframe smoke: FAILED at '$name': $*"; tail -n 20 "$name.log"; exit 1
    fi
    echo "  $name: ok ($((SECONDS - t0)) s)"
}

for AF in ${SMOKE_AIRFRAMES:-trainer x500}; do
    FILE="$EXAMPLES/$AF.toml"
    echo "own airframe $AF ($FILE)"
    if [ "$AF" = trainer ]; then
        PARAMS=C_m_alpha,C_m_q,C_m_delta_e
    else
        PARAMS=pitch_damping,pitch_mix
    fi
    step "$AF-trim" "$UAVDYN" trim --airframe "$FILE"
    step "$AF-modes" "$UAVDYN" modes --airframe "$FILE"
    step "$AF-simulate" "$UAVDYN" simulate --airframe "$FILE" --input doublet --duration 5 \
        --out "$AF-doublet.csv"
    step "$AF-generate-data" "$UAVDYN" generate-data --airframe "$FILE" --sorties 10 \
        --duration 15 --missions sysid_3211,aggressive --turbulent-fraction 0 --out "$AF-ds"
    step "$AF-identify" "$UAVDYN" identify --airframe "$FILE" --dataset "$AF-ds" \
        --params "$PARAMS" --out "$AF-id.toml" --quiet
    # the safe trainer may refuse a correction that does not help (an honest outcome: it
    # says why and writes no weights); anything else that fails is a failure
    if "$UAVDYN" train --airframe "$FILE" --dataset "$AF-ds" --epochs 3 --out "$AF-net.npz" \
            --quiet > "$AF-train.log" 2>&1; then
        echo "  $AF-train: ok, correction kept"
    elif grep -q "no weights written" "$AF-train.log" && [ -f "$AF-net_history.json" ]; then
        echo "  $AF-train: ok, correction refused: $(cut -c1-160 "$AF-train.log" | tail -n 1)"
    else
        echo "own-airframe smoke: FAILED at '$AF-train'"; tail -n 20 "$AF-train.log"; exit 1
    fi
    WEIGHTS=()
    [ -f "$AF-net.npz" ] && WEIGHTS=(--weights "$AF-net.npz")
    step "$AF-evaluate" "$UAVDYN" evaluate --airframe "$FILE" --dataset "$AF-ds" \
        --identified "$AF-id.toml" "${WEIGHTS[@]}" --out "$AF-eval.json"
    step "$AF-mpc-physics" "$UAVDYN" mpc --airframe "$FILE" --scenario pitch-step \
        --model physics --rti --out "$AF-mpc-physics"
    if [ -f "$AF-net.npz" ]; then
        step "$AF-mpc-hybrid" "$UAVDYN" mpc --airframe "$FILE" --scenario pitch-step \
            --model hybrid --weights "$AF-net.npz" --rti --out "$AF-mpc-hybrid"
    else
        echo "  $AF-mpc-hybrid: not flown (the trainer kept no correction)"
    fi
    step "$AF-export-c" "$UAVDYN" export-c --airframe "$FILE" "${WEIGHTS[@]}" --out "$AF-c"
    step "$AF-build-c" make -s -C "$AF-c"
    step "$AF-run-c" "./$AF-c/example"
    DISP=aerosonde_pm15; [ "$AF" = x500 ] && DISP=f450_pm15
    step "$AF-montecarlo-open" "$UAVDYN" montecarlo --airframe "$FILE" --dispersions "$DISP" \
        --runs 20 --duration 5 --no-progress --out "$AF-mc-open"
    step "$AF-montecarlo-closed" "$UAVDYN" montecarlo --airframe "$FILE" \
        --dispersions "$DISP" --runs 20 --duration 5 --closed-loop --no-progress \
        --out "$AF-mc-closed"
done
echo "own-airframe smoke: ok ($((SECONDS - START)) s)"
