"""rule.md's arithmetic on the candidates' compare.json files (paired against the shipped default).

    python docs/real_s40/verdict.py a6k b6k [--test]
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

O = Path("data/eval/real_s40")


def diff(set_name: str, cand: str) -> dict:
    c = json.loads((O / f"{set_name}_{cand}" / "compare.json").read_text())["overall"]
    return {k: (c[k]["diff"], c[k]["se_objects"], c[k]["wins"]) for k in ("psnr", "lpips")}


def main() -> None:
    args = [a for a in sys.argv[1:] if not a.startswith("--")]
    test = "--test" in sys.argv
    sets = ("t_real", "t_turn", "t_all") if test else ("realval", "ttval")
    print("| candidate | " + " | ".join(f"{s}: d PSNR (SE), wins | {s}: d LPIPS (SE)" for s in sets) + " |")
    print("|---|" + "---|---|" * len(sets))
    best = None
    for cand in args:
        d = {s: diff(s, cand) for s in sets}
        cells = []
        for s in sets:
            p, l_ = d[s]["psnr"], d[s]["lpips"]
            cells += [f"{p[0]:+.3f} ({p[1]:.3f}), {p[2]:.0%}", f"{l_[0]:+.4f} ({l_[1]:.4f})"]
        print(f"| {cand} | " + " | ".join(cells) + " |")
        if test:
            veto = d["t_real"]["psnr"][0] < 0 or d["t_real"]["lpips"][0] > 0.002 or d["t_all"]["psnr"][0] < -0.10
            print(f"\n{cand}: veto {'applies: not shipped' if veto else 'does not apply'}")
            continue
        eligible = (d["ttval"]["psnr"][0] >= -0.10 and d["ttval"]["lpips"][0] <= 0.002
                    and d["realval"]["lpips"][0] <= 0)
        print(f"  {cand}: eligible {eligible}")
        if eligible and (best is None or d["realval"]["psnr"][0] > best[1]["realval"]["psnr"][0]):
            best = (cand, d)
    if not test:
        if best is None:
            print("\nno candidate is eligible: the default stays")
        else:
            p, se, _ = best[1]["realval"]["psnr"]
            ship = p >= 0.20 and p >= 2 * se
            print(f"\npick {best[0]}: R d PSNR {p:+.3f} (SE {se:.3f}): "
                  f"{'passes step 3: score the test sets' if ship else 'below step 3: the default stays'}")


if __name__ == "__main__":
    main()
