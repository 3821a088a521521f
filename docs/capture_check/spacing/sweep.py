"""The pose check's verdict on `pairs.py`'s rows under variants of its rule (RULE.md's sixth rule): the rotations'
median over every pair, the directions' median over the pairs turning less than TD degrees, the split over the pairs
turning less than TS with agreement within AGREE. Prints, per variant, right models (within 1 degree) and models more
than 10 degrees off flagged, for each file given.

    PYTHONPATH=$PWD .venv/bin/python docs/capture_check/spacing/sweep.py PAIRS.jsonl [PAIRS.jsonl ...]  # the sweep
    PYTHONPATH=$PWD .venv/bin/python docs/capture_check/spacing/sweep.py --rule TD TS AGREE PAIRS.jsonl ...  # one ("none": no limit)
"""
import itertools, json, statistics, sys

from blender_mrvm.capture.check import MIN_PAIRS, SUSPECT_MEDIAN_DEG as THRESHOLD_DEG, _pieces as pieces


def suspect(row, td, ts, agree):
    pairs = row["pairs"]
    if len(pairs) < MIN_PAIRS:
        return False
    near = [p for p in pairs if td is None or p[2] < td]
    rot = statistics.median(p[0] for p in pairs)
    direction = statistics.median(p[1] for p in (near if len(near) >= MIN_PAIRS else pairs))
    names = sorted({p[3] for p in pairs} | {p[4] for p in pairs})
    judged = [p for p in pairs if ts is None or p[2] < ts]
    split = (pieces(names, [(p[3], p[4]) for p in judged if max(p[0], p[1]) <= agree])
             - pieces(names, [(p[3], p[4]) for p in judged]))
    return rot > THRESHOLD_DEG or direction > THRESHOLD_DEG or split > 0


def tally(rows, *rule):
    right = [r for r in rows if r["err"] < 1]
    far = [r for r in rows if r["err"] > 10]
    return (f"right {sum(suspect(r, *rule) for r in right)}/{len(right)}, "
            f">10 off {sum(suspect(r, *rule) for r in far)}/{len(far)}")


if __name__ == "__main__":
    args = sys.argv[1:]
    none = lambda v: None if v == "none" else float(v)  # noqa: E731
    if args[0] == "--rule":
        rules, args = [(none(args[1]), none(args[2]), float(args[3]))], args[4:]
    else:
        rules = list(itertools.product((None, 60, 50, 40), (None, 60, 50, 40, 30), (5, 7.5, 10)))
    files = {f: [json.loads(line) for line in open(f)] for f in args}
    for rule in rules:
        print(f"directions < {rule[0]}, split < {rule[1]}, agree {rule[2]}: "
              + " | ".join(f"{f.split('/')[-1]}: {tally(rows, *rule)}" for f, rows in files.items()))
