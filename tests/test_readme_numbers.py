"""README's findings name every study; the docs sections that report a study state numbers of its
committed results, and every number of README's "Speed" section and of docs/testing.md's cost comes from
the committed benchmark runs (benchmarks/results/, written by benchmarks/record.py, quickstart.py and
suite.py): a rerun that changes a number fails here until the text follows. The findings themselves,
analysis/README.md and docs/performance.md bind each number to its fact (tests/test_bindings.py)."""

from __future__ import annotations

import json
import re

import pytest
from conftest import ROOT

#: A number in prose: not part of a name (float32), an exponent (1e-14) or a date (dropped first).
NUMBER = re.compile(r"(?<![\w.])(?<!e-)\d[\d,]*(?:\.\d+)?")
DATE = re.compile(r"\d{4}-\d{2}-\d{2}")
#: A study of analysis/README.md's table: its number, script stems and results folders.
STUDY_ROW = re.compile(r"^\| \[study (\d+)\]\(#study-\d+\) \| .* \| (`\w+\.py`(?:, `\w+\.py`)*) \| (.*) \|$")


def numbers(text: str) -> set[str]:
    """Every number in ``text`` as written (thousands separators dropped, signs ignored; not in the
    bindings of tests/bindings.py, HTML comments)."""
    return {n.replace(",", "") for n in NUMBER.findall(DATE.sub("", re.sub(r"<!--.*?-->", "", text, flags=re.S)))}


def unmatched(cited: set[str], source: set[str]) -> list[str]:
    """The numbers of ``cited`` that no number of ``source`` rounds to at the cited precision (the
    README may round a results page's -5.08 to 5.1, never change it)."""
    values = sorted(float(n) for n in source)
    out = []
    for n in cited:
        half = 0.5 * 10.0 ** -len(n.partition(".")[2])
        if not any(abs(v - float(n)) <= half * (1 + 1e-9) for v in values):
            out.append(n)
    return sorted(out, key=float)


def section(text: str, title: str) -> str:
    """The body of the ``## title`` section of a markdown page."""
    body = text.split(f"\n## {title}\n", 1)[1]
    return body.split("\n## ", 1)[0]


def studies() -> dict[str, tuple[str, str]]:
    """Script stem -> (study number, results folder), from analysis/README.md's table (a study's scripts
    and folders in the same order)."""
    out = {}
    for line in (ROOT / "analysis" / "README.md").read_text().splitlines():
        if m := STUDY_ROW.match(line):
            folders = re.findall(r"\]\(results/(\w+)/README\.md\)", m.group(3))
            out |= {stem: (m.group(1), folder) for stem, folder in zip(re.findall(r"`(\w+)\.py`", m.group(2)), folders)}
    return out


def results_text(folder: str) -> str:
    """A study's conclusion page (``analysis/results/<folder>/README.md``, written by its script from
    its report); not the full report, whose thousands of numbers would match almost anything."""
    return (ROOT / "analysis" / "results" / folder / "README.md").read_text()


def data_rows() -> list[tuple[str, str]]:
    """(question, finding) of every row of README's "What the data says" table."""
    rows = []
    for line in section((ROOT / "README.md").read_text(), "What the data says").splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split(" | ")]
        if line.startswith("| ") and len(cells) == 2 and cells[0] not in ("question (script)", "---"):
            rows.append((cells[0], cells[1]))
    return rows


def test_the_table_has_a_row_per_study():
    """README's findings name each study of analysis/README.md's table (its first script), and only those;
    their numbers are bound to the studies' facts (tests/test_bindings.py)."""
    named = {m for q, _ in data_rows() for m in re.findall(r"`(\w+)\.py`", q)}
    firsts = {stem for stem, (number, _) in studies().items()
              if stem == min((s for s, (n, _) in studies().items() if n == number), key=list(studies()).index)}
    assert len({n for n, _ in studies().values()}) == 19
    assert named == firsts, "every study has a row in README's 'What the data says', and only studies"


def _leaves(value) -> list[float]:
    """Every number in a JSON value, numeric strings ("cpu_count": "2") included."""
    if isinstance(value, dict):
        return [x for v in value.values() for x in _leaves(v)]
    if isinstance(value, list):
        return [x for v in value for x in _leaves(v)]
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        return [float(value)]
    if isinstance(value, str) and re.fullmatch(r"\d+(\.\d+)?", value):
        return [float(value)]
    return []


def prose(text: str) -> str:
    """``text`` without code blocks and inline code (commands, option values, identifiers): the claims."""
    return re.sub(r"`[^`\n]*`", "", re.sub(r"```.*?```", "", text, flags=re.S))


RESULTS = ROOT / "benchmarks" / "results"
#: A committed run named in the text: ``engine.json`` or ``benchmarks/results/engine.json``.
RUN = re.compile(r"\b([a-z0-9][a-z0-9_-]*)\.json\b")


def benchmark_numbers(names: set[str] | None = None) -> set[str]:
    """Every number of the committed benchmark runs ``benchmarks/results/<name>.json`` (all of them
    when ``names`` is None), also as a percentage (a fraction 0.9998 is quoted as 99.98 %)."""
    paths = sorted(RESULTS.glob("*.json")) if names is None else [RESULTS / f"{n}.json" for n in sorted(names)]
    values = [x for p in paths for x in _leaves(json.loads(p.read_text()))]
    return {repr(abs(v)) for v in values} | {repr(abs(100 * v)) for v in values}


def cited_runs(text: str) -> set[str]:
    """The committed runs a text names (each must exist)."""
    names = set(RUN.findall(text))
    missing = [n for n in names if not (RESULTS / f"{n}.json").exists()]
    assert not missing, f"the text names runs that are not committed: {missing}"
    return names


@pytest.mark.parametrize("page, title", [("README.md", "Speed"), ("docs/testing.md", "Cost"),
                                         ("docs/testing.md", "Checking that the suite holds on other CPUs"),
                                         ("docs/sweep.md", "Measured figures")])
def test_speed_numbers_come_from_the_runs_they_cite(page, title):
    body = section((ROOT / page).read_text(), title)
    missing = unmatched(numbers(prose(body)), benchmark_numbers(cited_runs(body)))
    assert not missing, f"{page} '{title}': numbers not in the runs it names ({cited_runs(body)}): {missing}"


#: Sections of docs/ that report a study: (page, section, the study's results folder).
STUDY_SECTIONS = [("docs/tune.md", "Measured results", "tuning"), ("docs/tune.md", "Which tuner", "tuner_study"),
                  ("docs/scenarios.md", "Which settings separate what", "family_variants")]


@pytest.mark.parametrize("page, title, folder", STUDY_SECTIONS, ids=[p for p, _, _ in STUDY_SECTIONS])
def test_a_docs_section_reporting_a_study_states_its_results(page, title, folder):
    body = section((ROOT / page).read_text(), title)
    missing = unmatched(numbers(prose(body)), numbers(results_text(folder)))
    assert not missing, f"{page} '{title}': numbers not in analysis/results/{folder}/README.md: {missing}"


def test_the_solvability_oracles_page_states_the_codes_numbers():
    """docs/scenarios.md's "The solvability oracle": its numbers are the oracle's defaults and what
    follows from them and from the built-in families (not measurements)."""
    import math

    from jaxapf.config import VehicleConfig
    from jaxapf.scenarios import family_params, reach_cell
    from jaxapf.scenarios import solvability as oracle

    static, dynamic, trap = (family_params(f) for f in ("paper_static", "paper_dynamic", "trap"))
    run = dynamic.distance[0]
    side = run * math.cos(math.radians(dynamic.heading[0])) + 2 * oracle.MARGIN  # the searched box
    source = {
        oracle.RESOLUTION, oracle.MARGIN, oracle.REACH_RESOLUTION, math.sqrt(2) * oracle.RESOLUTION,
        reach_cell(side * side, v_max=VehicleConfig().v_max, t_max=dynamic.t_max), run, dynamic.t_max,
        2 * static.r_uav, 2 * static.cup_radius * math.sin(math.pi / 8) - 2 * static.radius,  # a cup's gap
        *(s / 2 for s in trap.gap_slack),  # a narrow gap's room on each side
        1, 2, 3, 8,  # SPEC 1 and 2, the 3×3 dilation, 8-connectivity
        oracle._BLOCK, *oracle._SIDESTEPS, *oracle._WAITS,  # the certificates' blocks, waypoints and waits
    }
    body = section((ROOT / "docs" / "scenarios.md").read_text(), "The solvability oracle")
    missing = unmatched(numbers(prose(body)), {repr(v) for v in source})
    assert not missing, f"docs/scenarios.md 'The solvability oracle': numbers not from the code: {missing}"


def test_the_dry_runs_cost_model_on_the_sweep_page_is_the_codes():
    """docs/sweep.md's cost model: its coefficients are jaxapf.sweep.STEP_COST_US, and the fit it names
    (18 configurations, N 10–40, I 10–60, M 4 and 16, vmap width 1,024) is benchmarks/fit_cost.py's
    (fit-cost.json)."""
    from jaxapf.sweep import STEP_COST_US

    body = (ROOT / "docs" / "sweep.md").read_text().split("### Dry run\n", 1)[1].split("\n## ", 1)[0]
    formula = re.search(r"`([\d.]+) \+ ([\d.]+)·N·I \+ ([\d.]+)·N·M \+ ([\d.]+)·N` µs", body).groups()
    assert len(formula) == len(STEP_COST_US)
    for written, coefficient in zip(formula, STEP_COST_US):
        assert not unmatched({written}, {repr(coefficient)}), (written, coefficient)
    fit = json.loads((RESULTS / "fit-cost.json").read_text())["runs"][0]
    rows = fit["rows"]
    described = {str(len(rows)), "10", "40", "60", "4", "16", "1024", "2"}
    assert described >= numbers(prose(body)) - {n.replace(",", "") for n in formula}
    assert (len(rows), min(r["horizon"] for r in rows), max(r["horizon"] for r in rows)) == (18, 10, 40)
    assert (min(r["iters"] for r in rows), max(r["iters"] for r in rows)) == (10, 60)
    assert {r["obstacles"] for r in rows} == {4, 16} and fit["fields"] == 1024


def test_the_quick_start_states_what_its_committed_run_measured():
    """README's quick-start paragraph: its times come from benchmarks/results/quickstart.json (written by
    benchmarks/quickstart.py, which runs the README's own commands), its sizes from the spec it runs,
    its Python version from pyproject.toml."""
    import tomllib

    from jaxapf.sweep import load_spec

    text = (ROOT / "README.md").read_text()
    paragraph = section(text, "Quick start").split("```", 1)[0]
    run = json.loads((ROOT / "benchmarks" / "results" / "quickstart.json").read_text())
    spec = load_spec(ROOT / run["sweep"][2])
    methods = len(dict(spec.grid)["method"]) if "method" in dict(spec.grid) else 1
    python = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["requires-python"]
    source = {repr(float(x)) for x in _leaves(run)} | {
        str(spec.fields), str(spec.fields * len(spec.families) * methods), python.lstrip(">="),
        run["environment"]["cpu_count"], str(len(spec.families))}
    missing = unmatched(numbers(paragraph), source)
    assert not missing, f"README quick start: numbers not from quickstart.json, the spec or pyproject: {missing}"


def test_the_offset_free_section_of_the_spec_states_the_declared_defaults():
    """docs/spec.md's offset-free tracking and robust CBF: its numbers are the declared defaults of the
    estimators' and the robust filters' gains (defaults and the brake share's bound), besides the formulas'
    constants and the citations' years."""
    from jaxapf.control import ESTIMATORS, FILTERS

    title = "### Beyond the paper: offset-free tracking and the robust CBF"
    body = (ROOT / "docs" / "spec.md").read_text().split(title, 1)[1].split("\n## ", 1)[0].split("\n### ", 1)[0]
    declared = {g.default for name in ("observer", "integral") for g in ESTIMATORS.get(name).gains}
    declared |= {g.default for g in FILTERS.get("braking_cbf").gains} | {
        g.high for g in FILTERS.get("braking_cbf").gains if g.high is not None}
    source = declared | {0, 1, 2, 2003, 2014}  # 1 − e^(−Δt/τ), Δt²/2, 1/(2Δt), δ = 0, the citations' years
    missing = unmatched(numbers(prose(body)), {repr(float(v)) for v in source})
    assert not missing, f"docs/spec.md offset-free section: numbers not from the declared gains: {missing}"
