#!/usr/bin/env bash
# Renders a run's report/index.html (or a comparison folder's index.html) in headless Chromium
# and saves a PNG, so that the report's layout and figures can be checked by eye.
#
#   scripts/screenshot_report.sh RUN_DIR OUT.png [WIDTH,HEIGHT]
#
# Needs Chromium (Debian: apt-get install -y chromium). Not part of CI.
set -euo pipefail

if [[ $# -lt 2 ]]; then
    echo "usage: $0 RUN_DIR OUT.png [WIDTH,HEIGHT]" >&2
    exit 2
fi
run_dir=$1
out=$2
size=${3:-1280,2400}

page="$run_dir/report/index.html"
[[ -f $page ]] || page="$run_dir/index.html"
if [[ ! -f $page ]]; then
    echo "no report in $run_dir: run 'hritest report $run_dir' first" >&2
    exit 2
fi

browser=$(command -v chromium || command -v chromium-browser || command -v google-chrome || true)
if [[ -z $browser ]]; then
    echo "Chromium not found; install it (Debian: apt-get install -y chromium)" >&2
    exit 2
fi

page=$(realpath "$page")
out=$(realpath -m "$out")
profile=$(mktemp -d)
trap 'rm -rf "$profile"' EXIT

"$browser" --headless --no-sandbox --disable-gpu --disable-background-networking \
    --disable-component-update --no-first-run --hide-scrollbars --user-data-dir="$profile" \
    --screenshot="$out" --window-size="$size" "file://$page" >/dev/null 2>&1
[[ -s $out ]] || { echo "Chromium wrote no screenshot to $out" >&2; exit 1; }
echo "$out"
