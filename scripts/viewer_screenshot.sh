#!/usr/bin/env bash
# Open a dataset in the Rerun viewer on a virtual display and save a screenshot of the whole screen: the check
# a person makes by looking. Needs the Debian packages xvfb and imagemagick.
#   bash scripts/viewer_screenshot.sh DIR EPISODE OUT.png [SECONDS_TO_WAIT]
set -euo pipefail
dir=$1 episode=$2 shot=$3 wait=${4:-45}
cd "$(dirname "$0")/.."
display=:${BABBLEGEN_DISPLAY:-99}
Xvfb "$display" -screen 0 1600x900x24 >/dev/null 2>&1 &
xvfb=$!
trap 'kill $(jobs -p) 2>/dev/null || true; pkill -f "rerun.*--port" 2>/dev/null || true' EXIT
sleep 2
DISPLAY=$display .venv/bin/babblegen view "$dir" --episode "$episode" &
sleep "$wait"
DISPLAY=$display import -window root "$shot"
echo "screenshot: $shot"
kill $xvfb
