#!/bin/sh
# Regenerate datasets/synth_board_640 bit-for-bit from its seed (run from the repository root):
#   sh datasets/regenerate_synth_board.sh && git status --short datasets/   # -> no changes
# A 640x480 radtan-5 chessboard set: 6 board views (1 partial, 1 bowed "bad" view), 1 blank frame, 1 truncated PNG.
set -e
PYTHON="${PYTHON:-python}"
rm -f datasets/synth_board_640/img_*.png datasets/synth_board_640/truth.json
"$PYTHON" -m radarcal synth board datasets/synth_board_640 --board chessboard --cols 9 --rows 6 --square 0.025 \
    --image-size 640x480 --model pinhole5 --views 6 --partial 1 --blank 1 --corrupt 1 --bad-view --noise 1.0 --blur 0.6 --seed 0
