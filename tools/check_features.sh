#!/usr/bin/env bash
# The library without its command line: a dependent crate with `default-features = false` must
# compile none of the command-line crates (clap, indicatif, plotters, gif, anyhow, ctrlc), and the
# library must build that way. Run by .ci/run; see README "Using gpm as a library".
set -euo pipefail
cd "$(dirname "$0")/.."
cli_crates=(clap indicatif plotters gif anyhow ctrlc nix)
tree="$(cargo tree -e normal --no-default-features --prefix none --format '{p}')"
bad=0
for c in "${cli_crates[@]}"; do
    if grep -E "^${c} v" <<<"$tree" >/dev/null; then
        echo "error: '${c}' is a normal dependency of gpm without default features:" >&2
        cargo tree -e normal --no-default-features -i "$c" >&2 || true
        bad=1
    fi
done
# the same crates must still be what the `cli` feature brings (else this check checks nothing)
tree_cli="$(cargo tree -e normal --prefix none --format '{p}')"
for c in "${cli_crates[@]}"; do
    if ! grep -E "^${c} v" <<<"$tree_cli" >/dev/null; then
        echo "error: '${c}' is not a dependency of the cli feature any more: update this script" >&2
        bad=1
    fi
done
[ "$bad" -eq 0 ] || exit 1
cargo build --release --no-default-features --lib
echo "ok: without default features gpm depends on none of ${cli_crates[*]} and the library builds"
