#!/usr/bin/env bash
# The test command of the README: the whole suite on the default device,
# then the GPU suites again with lavapipe's 4-wide subgroups.
set -euo pipefail
cd "$(dirname "$0")/.."

bash scripts/setup.sh

cargo test --workspace

# On lavapipe this exercises 4-wide subgroups; elsewhere it is a second run.
# The 4-minute method test (train_quality) runs once, above.
echo "== GPU tests again with LP_NATIVE_VECTOR_WIDTH=128 (lavapipe subgroup size 4)"
LP_NATIVE_VECTOR_WIDTH=128 cargo test -p tgs-tests -- --skip method_on_glass
