"""Tables of docs/capture_check/README.md from the benches' JSON lines.

    .venv/bin/python docs/capture_check/summarize.py docs/capture_check/results
"""
import json
import sys
from pathlib import Path

res = Path(sys.argv[1])


def reg(m):
    return m.get("registered", 0)


def sets(prefix):
    """(set letter, rows) of each results/<prefix>_<set>.jsonl there is."""
    for s in "abcd":
        f = res / f"{prefix}_{s}.jsonl"
        if f.is_file():
            yield s.upper(), [json.loads(x) for x in f.open()]


POLICIES = {
    "shipped: view graph; the guess when photos are left out, the one placing more kept":
        lambda r: r["guess"] if reg(r["vg"]) < r["n"] and reg(r["guess"]) > reg(r["vg"]) else r["vg"],
    "view graph only": lambda r: r["vg"],
    "guess only": lambda r: r["guess"],
    "both always; more placed, tie: lower reprojection error":
        lambda r: max([r["vg"], r["guess"]], key=lambda m: (reg(m), -m.get("reproj", 9))),
    "both always; more placed, tie: more points":
        lambda r: max([r["vg"], r["guess"]], key=lambda m: (reg(m), m.get("points", 0))),
}
print("| set | policy | all placed, within 1 degree | of which arcs | ring12 | photos placed |")
print("|---|---|---|---|---|---|")
for s, rows in sets("mappings"):
    for name, pick in POLICIES.items():
        kept = [pick(r) for r in rows]
        ok = [reg(m) == r["n"] and m.get("rot_med", 1e9) < 1 for m, r in zip(kept, rows)]
        arcs = sum(o for o, r in zip(ok, rows) if r["subset"] != "ring12")
        ring = sum(o for o, r in zip(ok, rows) if r["subset"] == "ring12")
        placed = sum(reg(m) for m in kept) / sum(r["n"] for r in rows)
        n_arcs = sum(r["subset"] != "ring12" for r in rows)
        print(f"| {s} | {name} | {sum(ok)} of {len(rows)} | {arcs} of {n_arcs} "
              f"| {ring} of {sum(r['subset'] == 'ring12' for r in rows)} | {placed:.3f} |")
print()
print("| set | statistic, threshold | models kept | right (within 1 degree) flagged | largest median of a right one "
      "| over 10 degrees flagged | 3-10 degrees flagged | slowest check |")
print("|---|---|---|---|---|---|---|---|")
for s, rows in sets("check"):
    for key, thr, dirs in (("all", 3.0, False), ("general", 1.5, False), ("general", 1.5, True)):
        def flag(r):
            m, d = r[key]["median"], r[key].get("direction")
            return m is not None and (m > thr or (dirs and d is not None and d > thr))
        right = [r for r in rows if r["rot_med"] < 1]
        far = [r for r in rows if r["rot_med"] > 10]
        mid = [r for r in rows if 3 < r["rot_med"] <= 10]
        largest = max(max(r[key]["median"] or 0, r[key].get("direction") or 0 if dirs else 0) for r in right)
        name = f"{key}{' + directions' if dirs else ''}, {thr}"
        print(f"| {s} | {name} | {len(rows)} | {sum(map(flag, right))} of {len(right)} "
              f"| {largest:.2f} | {sum(map(flag, far))} of {len(far)} "
              f"| {sum(map(flag, mid))} of {len(mid)} | {max(r[key]['seconds'] for r in rows):.2f} s |")
