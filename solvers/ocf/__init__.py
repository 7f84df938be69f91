"""The overlapping coalition formation game (OCF) engine and its two rule-based players:
ROCF (uniform choice) and HOCF (heuristic choice). The learned player is in `..tsac`."""
