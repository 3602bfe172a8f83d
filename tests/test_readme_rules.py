"""The rules README.md keeps for itself, checked so they do not decay: short answers, every shipped spec and
every registry named, the package's version, no stray binaries in the repository."""

import re
import subprocess

import pytest

from jaxapf.cli import build_parser

#: Most words of one answer in "What the data says" (the table's second column; a word holds a letter, so
#: figures and intervals are not counted), as the README says above the table.
ANSWER_WORDS = 30
#: Where tracked binary files may live: the README's images, test data and the studies' committed results.
BINARY_FOLDERS = ("docs/img/", "tests/data/", "analysis/results/", "jaxapf/compare/scorecards/")


def _section(readme: str, title: str) -> str:
    return re.search(rf"^## {re.escape(title)}\n(.*?)(?=^## )", readme, re.S | re.M).group(1)


def _plain(text: str) -> str:
    return re.sub(r"<!--.*?-->", "", text)


def words(text: str) -> int:
    """Words a reader counts: runs of characters between spaces holding a letter (not a figure), bindings and
    Markdown emphasis left out."""
    return sum(1 for w in re.sub(r"[*`|]", " ", _plain(text)).split() if re.search(r"[A-Za-z]", w))


def answers(readme: str) -> list[tuple[str, str]]:
    """(question, answer) of every row of the "What the data says" table."""
    rows = [line for line in _section(readme, "What the data says").splitlines() if line.startswith("| ")]
    cells = [[c.strip() for c in re.split(r"(?<!\\)\|", row)[1:-1]] for row in rows[2:]]  # header, rule
    return [(question, answer) for question, answer in cells]


def test_every_answer_is_short(repo_root):
    readme = (repo_root / "README.md").read_text()
    assert "at most thirty words" in _section(readme, "What the data says") and ANSWER_WORDS == 30
    long = [(q, words(a)) for q, a in answers((repo_root / "README.md").read_text()) if words(a) > ANSWER_WORDS]
    assert not long, f"answers over {ANSWER_WORDS} words: {long}"


def test_the_word_count_counts_what_a_reader_sees():
    assert words("**No.** `basic` 35.2<!--=study/x:y--> %, *worse*<!--=study/x:z--> [−0.8, +0.1]") == 3


def test_every_shipped_spec_is_named(repo_root):
    readme = (repo_root / "README.md").read_text()
    sentence = re.search(r"Shipped specs:(.*?)\n\n", readme, re.S).group(1)
    named = set(re.findall(r"`([\w-]+\.toml)`", sentence))
    shipped = {p.name for p in (repo_root / "sweeps").glob("*.toml")}
    assert shipped - named == set(), f"specs in sweeps/ the README does not name: {sorted(shipped - named)}"
    assert named - shipped == set(), f"specs the README names that sweeps/ lacks: {sorted(named - shipped)}"


def test_every_registry_of_jaxapf_list_is_named(repo_root):
    readme = (repo_root / "README.md").read_text()
    line = re.search(r"`jaxapf list ([^`]+)`", readme).group(1)
    named = set(line.replace("\\|", "|").split("|"))
    parser = build_parser()
    sub = next(a for a in parser._subparsers._group_actions[0].choices["list"]._actions if a.dest != "help")
    assert named == set(sub.choices), f"README names {sorted(named)}, `jaxapf list` takes {sorted(sub.choices)}"


def test_the_package_says_its_version(capsys):
    from importlib.metadata import version

    with pytest.raises(SystemExit) as done:
        build_parser().parse_args(["--version"])
    assert done.value.code == 0 and capsys.readouterr().out.strip() == f"jaxapf {version('jaxapf')}"


def _binary(data: bytes) -> bool:
    return b"\0" in data[:8192]


def test_no_tracked_binary_outside_its_folders(repo_root):
    """Binary files (a NUL byte in their first 8 KiB) are tracked only under BINARY_FOLDERS."""
    tracked = subprocess.run(["git", "ls-files", "-z"], cwd=repo_root, capture_output=True, check=True).stdout
    stray = [name for name in tracked.decode().split("\0") if name and not name.startswith(BINARY_FOLDERS)
             and (repo_root / name).is_file() and _binary((repo_root / name).read_bytes()[:8192])]
    assert not stray, f"tracked binary files outside {', '.join(BINARY_FOLDERS)}: {stray}"


def test_the_binary_check_finds_a_wheel():
    assert _binary(b"PK\x03\x04\x14\x00\x00\x00\x08\x00") and not _binary(b"name = 'x'\n")


def test_the_quick_comparison_finishes_in_three_minutes_by_its_record(repo_root):
    """docs/compare.md offers sweeps/compare-quick.toml as the protocol in minutes: its record says so."""
    import json

    record = json.loads((repo_root / "benchmarks" / "results" / "compare-quick.json").read_text())
    run = record["runs"][0]
    assert run["command"].startswith("jaxapf compare sweeps/compare-quick.toml") and run["compilation_cache"] == "empty"
    assert run["cold_s"] <= 180 and run["environment"]["cpu_count"] == "2"


def test_every_documented_time_of_the_quick_start_and_the_suite_names_its_cache(repo_root):
    """A time in the README's set-up section (the quick start's, the suite's) holds under a condition a reader
    must know: the sentence that states it says which compilation cache it ran with."""
    readme = (repo_root / "README.md").read_text()
    setup = _section(readme, "Quick start")
    sentences = re.split(r"(?<=[.;])\s", setup)
    timed = [s for s in sentences if re.search(r"<!--=bench/(quickstart|suite-[a-z-]+):", s)]
    assert len(timed) >= 2
    blind = [_plain(s) for s in timed if not re.search(r"cache", s)]
    assert not blind, f"times that do not say which cache they ran with: {blind}"


#: How far a recorded suite's test count may be from today's before its times stop describing the suite.
SUITE_COUNT_TOLERANCE = 0.02


def suite_records(repo_root) -> dict[str, set[str]]:
    """Every suite record (``benchmarks/results/suite-*.json``) the README and docs name, by a binding
    (``bench/suite-X``) or by its file name, with the documents naming it."""
    named: dict[str, set[str]] = {}
    for doc in [repo_root / "README.md", *sorted((repo_root / "docs").glob("*.md"))]:
        for name in re.findall(r"bench/(suite-[a-z0-9-]+)|\b(suite-[a-z0-9-]+)\.json", doc.read_text()):
            named.setdefault(next(n for n in name if n), set()).add(doc.name)
    return named


def tier_counts(request, repo_root) -> dict[str, int]:
    """How many tests each tier holds today: from this run where it collected the whole suite, else from
    ``pytest --collect-only``."""
    import sys

    if getattr(request.config, "jaxapf_tiers", None):
        return request.config.jaxapf_tiers
    counts = {}
    for tier, marks in (("all", []), ("fast", ["-m", "not slow"])):
        out = subprocess.run([sys.executable, "-m", "pytest", "--collect-only", "-q", "-n", "0", "-p",
                              "no:cacheprovider", *marks], cwd=repo_root, capture_output=True, text=True).stdout
        counts[tier] = sum(1 for line in out.splitlines() if "::" in line)
    return counts


def test_every_suite_time_stated_comes_from_a_record_of_todays_suite(request, repo_root):
    """A suite time in the README or docs holds for the suite that was measured: its record's test count is
    today's for that tier, within 2 %, so a suite that grows past its records fails here until they are rerun
    (python benchmarks/suite.py; docs/testing.md)."""
    import json

    named = suite_records(repo_root)
    assert {"suite-fast", "suite-all"} <= set(named), named
    counts = tier_counts(request, repo_root)
    stale = []
    for name, docs in sorted(named.items()):
        path = repo_root / "benchmarks" / "results" / f"{name}.json"
        record = json.loads(path.read_text()) if path.exists() else {}
        tests, tier = record.get("tests"), record.get("tier")
        today = counts.get(tier)
        if today is None or not isinstance(tests, int) or abs(tests - today) > SUITE_COUNT_TOLERANCE * today:
            stale.append(f"{name} ({', '.join(sorted(docs))}): {tests} tests of tier {tier!r}, today {today}")
    assert not stale, "suite records that no longer describe the suite (rerun benchmarks/suite.py): " + "; ".join(stale)
