"""A newcomer's wait for a row on scorecard v1, and that the row is the method's: ``basic`` scored under another
name in a fresh process with an empty compilation cache (selection, drift check, test flights and leaderboard
included), its row beside ``basic``'s stored one and its primary verdicts against ``basic``.

    python benchmarks/scorecard.py        # one JSON object (benchmarks/record.py keeps it as scorecard-basic)

A planner of ``basic``'s cost must be ranked within 10 minutes on the 2-core CPU (docs/scorecard.md); ``basic``
scored again must reproduce its stored row and be *equivalent* to it on every primary comparison.
"""

from __future__ import annotations

import json
import pathlib
import sys

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))

from timed import measure  # noqa: E402

#: The label of the row (a zoo member's own name is refused).
NAME = "basic_timed"
#: The leaderboard's numbers of a row.
ROW = ("rank", "episodes", "success", "success_lo", "success_hi", "collision", "collision_lo", "collision_hi",
       "clearance_median", "clearance_median_lo", "clearance_median_hi")


def read(out: pathlib.Path) -> dict:
    """The row, basic's row and the primary comparisons with basic, from what the command wrote."""
    import pandas as pd

    board = pd.read_csv(out / "leaderboard.csv").set_index("method")
    comp = pd.read_csv(out / "comparisons.csv")
    row = {c: board.loc[NAME, c].item() for c in ROW}
    basic = {c: board.loc["basic", c].item() for c in ROW}
    primary = comp[comp["holm_family"] == "primary"]
    versus = primary[primary["member"] == "basic"]
    same = all(row[c] == basic[c] or (row[c] != row[c] and basic[c] != basic[c]) for c in ROW)  # NaN as NaN
    return {"name": NAME, "members": len(board), "row": row, "basic_row": basic, "row_equals_basic": same,
            "primary_family": len(primary), "primary_groups": sorted(set(primary["family"])),
            "primary_vs_basic": json.loads(versus[["metric", "family", "n_pairs", "delta", "delta_lo", "delta_hi",
                                                   "confidence", "verdict"]].to_json(orient="records"))}


def main(argv: list[str] | None = None) -> int:
    import argparse

    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--card", default="v1", help="the scorecard (default v1; a folder holding one, to try the script)")
    args = p.parse_args(argv)
    card = str(pathlib.Path(args.card).resolve()) if pathlib.Path(args.card).is_dir() else args.card  # run from ROOT
    command = ["scorecard", "--card", card, "--method", "basic", "--name", NAME, "--quiet"]
    print(json.dumps(measure(command, read), indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
