#!/usr/bin/env bash
# Regenerate paper-figures/ (the figures the README shows) from a committed reference
# campaign, and nothing else: `scripts/reproduce.sh` never writes them, so a reproduce run
# leaves the work tree clean.
#
# Usage: scripts/paper-figures.sh [REFERENCE_CAMPAIGN_FOLDER]
#   default: the reference campaign named in paper-figures/README.md
# The folder must be committed and marked "reference": true in its manifest.json.
set -euo pipefail
cd "$(dirname "$0")/.."
[ -f "$HOME/.cargo/env" ] && . "$HOME/.cargo/env"
ref=${1:-$(sed -n 's/^`\(results\/[^`]*\)\/runs.csv`.*/\1/p' paper-figures/README.md | head -n 1)}
if [ -z "$ref" ] || [ ! -f "$ref/runs.csv" ]; then
    echo "paper-figures: no reference campaign '$ref' (give its folder, e.g. results/<fingerprint>/quick)" >&2
    exit 2
fi
if ! grep -q '"reference": true' "$ref/manifest.json" 2>/dev/null; then
    echo "paper-figures: $ref is not a reference campaign (its manifest.json lacks \"reference\": true)" >&2
    exit 2
fi
if ! git ls-files --error-unmatch "$ref/runs.csv" >/dev/null 2>&1; then
    echo "paper-figures: $ref/runs.csv is not committed: commit the reference campaign first" >&2
    exit 2
fi
cargo build --profile o3 -p mpm-bench
target/o3/mpm-bench figures --results "$ref" --out paper-figures
