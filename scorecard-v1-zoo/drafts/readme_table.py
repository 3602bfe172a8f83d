"""Draft: print the README's scorecard table from v1's facts.json, every number bound (then remove)."""
import json
import pathlib

ROOT = pathlib.Path(__file__).resolve().parents[2]
f = json.loads((ROOT / "jaxapf/compare/scorecards/v1/facts.json").read_text())
B = "scorecard/v1"


def num(key, m, scale=100, digits=1):
    v = f[key][m]
    if v is None:
        return "–"
    text = f"{abs(scale * v):,.{digits}f}"
    sign = "−" if scale * v < 0 and text.strip("0.,") else ""
    return f"{sign}{text}<!--={B}:{key}.{m}{'×100' if scale == 100 else ''}-->"


order = sorted(f["rank"], key=lambda m: (f["rank"][m], m))
print("| rank | method | success % [seeds' t interval] | collision % | median clearance m | selection s |")
print("|---:|---|---|---|---|---:|")
for m in order:
    print(f"| {f['rank'][m]}<!--={B}:rank.{m}--> | `{m}` | {num('success', m)} [{num('success_lo', m)}, "
          f"{num('success_hi', m)}] | {num('collision', m)} [{num('collision_lo', m)}, {num('collision_hi', m)}] | "
          f"{num('clearance_median', m, 1, 2)} | {num('selection_seconds', m, 1, 0)} |")
