#!/usr/bin/env bash
# ARCHITECTURE.md's code map against the source tree: every `src/**/*.rs` file of the
# workspace is named in it, and every file it names exists.
#
# The code map is the first ``` block after the heading "## Code map". A line that starts in
# column 0 with `<crate>/src/` opens that crate's list, any other line starting in column 0
# (`mpm-core/tests/ ...`) closes it; the rest of such a line is prose. On the indented lines of
# a crate's list each `path.rs` is relative to the crate's `src/`, and a bare `name.rs` lies in
# the folder of the last path with a folder before it on the same line (`material/j2.rs ...;
# eos.rs: ...` names material/eos.rs), or in `src/` itself when there is none.
#
# Usage: scripts/codemap-check.sh   (exit 0: the map and the tree agree; 1: they do not, each
# difference named; 2: no code map found)
set -euo pipefail
cd "$(dirname "$0")/.."

map=ARCHITECTURE.md
named=$(awk '
    /^## Code map/ { inmap = 1; next }
    inmap && /^```/ { if (fence) exit; fence = 1; next }
    !fence { next }
    /^[^ ]/ {
        crate = ""
        if (match($0, /^[A-Za-z0-9_-]+\/src\//)) crate = substr($0, 1, RLENGTH)
        next
    }
    crate == "" { next }
    {
        line = $0; dir = ""
        while (match(line, /[A-Za-z0-9_\/]+\.rs/)) {
            tok = substr(line, RSTART, RLENGTH); line = substr(line, RSTART + RLENGTH)
            if (index(tok, "/")) { dir = tok; sub(/[^\/]*$/, "", dir); print crate tok }
            else print crate dir tok
        }
    }' "$map" | sort -u)
if [ -z "$named" ]; then
    echo "codemap-check: $map has no code map (a \`\`\` block after \"## Code map\" with <crate>/src/ lines)" >&2
    exit 2
fi

# Tracked files and new ones git does not ignore, still present in the work tree.
actual=$(git ls-files --cached --others --exclude-standard -- ':(glob)*/src/**/*.rs' |
    while IFS= read -r f; do [ -f "$f" ] && printf '%s\n' "$f"; done | sort -u)

missing=$(comm -23 <(printf '%s\n' "$actual") <(printf '%s\n' "$named"))
gone=$(comm -13 <(printf '%s\n' "$actual") <(printf '%s\n' "$named"))
for f in $missing; do
    crate=${f%%/src/*}
    echo "codemap-check: $f is not in $map's code map: add a line for ${f#*/src/} under $crate/src/" >&2
done
for f in $gone; do
    echo "codemap-check: $map's code map names ${f#*/src/} under ${f%%/src/*}/src/, which does not exist: remove or rename it" >&2
done
if [ -n "$missing$gone" ]; then exit 1; fi
echo "codemap-check: $map names all $(printf '%s\n' "$actual" | wc -l) source files of the workspace"
