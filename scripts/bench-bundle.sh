#!/usr/bin/env bash
# Build every benchmark and the tgs binary here, and gather them into one
# folder that runs on a GPU machine with no Rust toolchain (what
# perf/RESULTS.md's NVIDIA rows were measured with):
#
#   bash scripts/bench-bundle.sh [DIR]        # default DIR: target/bench-bundle
#   # copy DIR to the GPU machine (same CPU architecture, a Vulkan loader), then there:
#   bash DIR/run.sh [OUT]                     # every suite; logs and JSON in OUT
#
# run.sh takes TGS_DEVICE (default "nvidia"), and BENCHES (default: every
# suite) to pick suites by name.
set -euo pipefail
cd "$(dirname "$0")/.."
dir="${1:-target/bench-bundle}"

# One cargo invocation lists the bench executables it built.
mapfile -t exes < <(cargo bench --no-run --message-format=json -p tgs-perf 2>/dev/null |
    grep -o '"target":{[^}]*"kind":\["bench"\][^}]*}.*"executable":"[^"]*"' |
    sed -E 's/.*"name":"([^"]*)".*"executable":"([^"]*)"/\1 \2/')
if [ "${#exes[@]}" -eq 0 ]; then
    echo "bench-bundle: cargo built no bench executables (run cargo bench --no-run -p tgs-perf to see why)" >&2
    exit 1
fi
cargo build --release -p tgs

rm -rf "$dir"
mkdir -p "$dir"
names=()
for e in "${exes[@]}"; do
    name="${e%% *}"
    cp "${e#* }" "$dir/$name"
    names+=("$name")
done
cp target/release/tgs "$dir/tgs"

cat > "$dir/run.sh" <<EOF
#!/usr/bin/env bash
# Every tgs benchmark suite on this machine's GPU (see scripts/bench-bundle.sh).
set -uo pipefail
here="\$(cd "\$(dirname "\$0")" && pwd)"
out="\${1:-\$here/results}"
mkdir -p "\$out"
export TGS_DEVICE="\${TGS_DEVICE:-nvidia}" CARGO_TARGET_DIR="\$out"
"\$here/tgs" devices | tee "\$out/devices.txt"
status=0
for b in \${BENCHES:-${names[*]}}; do
    echo "== \$b"
    "\$here/\$b" --bench 2>&1 | tee "\$out/bench-\$b.log"
    rc=\${PIPESTATUS[0]}
    [ "\$rc" -eq 0 ] || { echo "== \$b failed (exit \$rc)"; status=1; }
done
echo "logs in \$out, JSON in \$out/tgs-bench/"
exit \$status
EOF
chmod +x "$dir/run.sh"
echo "bench bundle in $dir (${names[*]} + tgs); on the GPU machine: bash $dir/run.sh"
