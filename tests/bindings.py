"""Numbers in prose bound to the one fact each reports.

A number in a bound document carries, right after it, an HTML comment naming the value it reports in a
committed result (invisible where the Markdown is rendered)::

    the engine ran 230,862<!--=bench/engine:runs.0.engine.steps_per_s--> scenario-steps/s
    falls by 11.3<!--=study/robustness:wind_mean_change.direction×100--> points
    the gradient tuner is *better*<!--=study/tuner_study:verdict.d16--> in 3<!--=...--> of 6 runs

- **source**: ``bench/NAME`` is ``benchmarks/results/NAME.json``, ``study/FOLDER`` is
  ``analysis/results/FOLDER/facts.json``, ``scorecard/VERSION`` the stored zoo's
  ``jaxapf/compare/scorecards/VERSION/facts.json``;
- **key**: a path into that JSON, its parts separated by ``.`` (a key holding a dot or a space is matched
  whole, the longest first), list items by their index;
- **transform** (optional): ``×N`` or ``÷N`` by a number, ``÷KEY`` by another fact of the same source (a
  ratio), a leading ``-`` to negate.

A bound number must be the fact rounded to the decimals written (strictly nearer it than to any other
number of that precision, or its correctly rounded text); a sign written before it (``−``, ``+``) must be
the fact's, a number written without one is compared by size ("falls by 11.3" for a change of -0.113). A
verdict word (``*better*``, ``*worse*``, ``*equivalent*``, ``*inconclusive*``) bound the same way must be
the fact's text, or, bound to a count of verdicts, the last word of the count's key
(``*worse* in 7<!--=…:reciprocity_verdicts.swarm_success/worse--> of 60`` binds both to the one count).
A bold answer (``**No<!--=study/learned_weight:answer-->, …**``, one of :data:`jaxapf.stats.ANSWERS`) is
bound to an answer fact, ``{"word": ..., "verdicts": {name: verdict}}``: the word written must be the
fact's, and the fact's word the one :func:`jaxapf.stats.answer` derives from its verdicts.
In a strict document every number is bound, but identifiers: inline code, dates, "study
11", "§3", "eq. 2". :func:`problems` says what is wrong with a text; :func:`mutations` gives every ±1 change
of a bound number's last digit and every swap of a bound verdict word, each of which :func:`problems` must
catch (tests/test_bindings.py).

``python tests/bindings.py check FILE...`` lists what is wrong in each file (every number strict);
``python tests/bindings.py suggest FILE [SOURCE ...]`` prints, for each unbound number of FILE, the keys of
the named sources whose value it is (a start for binding a document by hand).
"""

from __future__ import annotations

import functools
import json
import pathlib
import re
import sys
from typing import Any, Iterator

ROOT = pathlib.Path(__file__).resolve().parents[1]
VERDICTS = ("better", "worse", "equivalent", "inconclusive")
#: A binding: ``<!--=SOURCE:KEY[TRANSFORM]-->``.
BINDING = re.compile(r"<!--=(?P<source>(?:bench|study|scorecard)/[\w.-]+):(?P<expr>[^>]*?)-->")
#: A number as prose writes it: thousands separators, decimals; not part of a name (float32).
NUMBER = re.compile(r"(?<![\w.])(?P<digits>\d[\d,]*(?:\.\d+)?)")
#: What is not a reported number: code, dates, references to a study, section, equation, issue or row,
#: HTML comments (the bindings themselves), link targets, versions (0.10.2), exponents (1e-14) and names
#: with a number (AVX-512).
IDENTIFIERS = re.compile(r"```.*?```|`[^`\n]*`|<!--.*?-->|\]\([^)]*\)|\d{4}-\d{2}-\d{2}|\d+(?:\.\d+){2,}|"
                         r"\d(?:\.\d+)?e-?\d+|[A-Za-z]+-\d+|"
                         r"\b(?:[Ss]tud(?:y|ies)|§|[Ee]q\.|[Ii]ssue|[Rr]ows?|[Cc]ommit)\s*\d[\d, and–-]*", re.S)
VERDICT = re.compile(r"\*(?P<word>" + "|".join(VERDICTS) + r")\*")
#: A bold answer's first words, right before its binding.
ANSWER = re.compile(r"\*\*(?P<word>Yes|No|Not shown|In part|Mixed)$")


@functools.cache
def _source(source: str) -> Any:
    kind, name = source.split("/", 1)
    path = {"bench": ROOT / "benchmarks" / "results" / f"{name}.json",
            "study": ROOT / "analysis" / "results" / name / "facts.json",
            "scorecard": ROOT / "jaxapf" / "compare" / "scorecards" / name / "facts.json"}[kind]
    return json.loads(path.read_text())


def lookup(data: Any, key: str) -> Any:
    """The value at ``key`` (parts separated by ``.``; a part holding dots matched whole, longest first)."""
    if key == "":
        return data
    if isinstance(data, list):
        head, _, rest = key.partition(".")
        return lookup(data[int(head)], rest)
    if isinstance(data, dict):
        for name in sorted((k for k in data if key == k or key.startswith(f"{k}.")), key=len, reverse=True):
            try:
                return lookup(data[name], key[len(name) + 1:])
            except (KeyError, IndexError, ValueError, TypeError):
                continue
    raise KeyError(key)


def value(source: str, expr: str) -> Any:
    """The value a binding names: ``[-]KEY[×N|÷N|÷KEY]``."""
    negate = expr.startswith("-")
    expr = expr[1:] if negate else expr
    match = re.fullmatch(r"(?P<key>[^×÷]+)(?:(?P<op>[×÷])(?P<by>.+))?", expr)
    if match is None:
        raise KeyError(expr)
    data = _source(source)
    x = lookup(data, match["key"].strip())
    if match["op"]:
        by = match["by"].strip()
        factor = float(by) if re.fullmatch(r"[\d.]+(?:e-?\d+)?", by) else float(lookup(data, by))
        x = float(x) * factor if match["op"] == "×" else float(x) / factor
    return -float(x) if negate else x


def _matches(written: str, sign: str, fact: Any) -> bool:
    if isinstance(fact, bool) or not isinstance(fact, (int, float)):
        return False
    text = written.replace(",", "")
    decimals = len(text.partition(".")[2])
    fact = float(fact)
    shown = float(text) * (-1 if sign in "−-" and sign else 1)
    target = fact if sign else abs(fact)
    if f"{target:.{decimals}f}" == f"{shown:.{decimals}f}":
        return True
    return abs(target - shown) < 0.5 * 10.0 ** -decimals * (1 - 1e-9)


def problems(text: str, strict: bool = True) -> list[str]:
    """What is wrong with ``text``: bindings that name no fact or do not match the number or verdict
    before them, and (``strict``) numbers with no binding."""
    out = []
    bound_at = set()
    for b in BINDING.finditer(text):
        before = text[max(0, b.start() - 80):b.start()]  # what a binding follows ends right before it
        offset = b.start() - len(before)
        where = f"…{before[-40:]}"
        verdict = re.search(r"\*(\w+)\*$", before)
        number = re.search(r"(?<![\w.])(?P<sign>[−+-]?)(?P<digits>\d[\d,]*(?:\.\d+)?)$", before)
        if number is not None:
            bound_at.add(offset + number.start("digits"))
        try:
            fact = value(b["source"], b["expr"])
        except (KeyError, IndexError, ValueError, TypeError, OSError):
            out.append(f"{where}: no fact {b['source']}:{b['expr']}")
            continue
        said = ANSWER.search(before)
        if said is not None:
            out += [f"{where}: {p}" for p in _answer_problems(said["word"], fact, f"{b['source']}:{b['expr']}")]
            continue
        if verdict is not None:
            # a verdict word is its fact's text, or (a count of verdicts) the last word of its count's key
            counted = not isinstance(fact, str) and re.split(r"[./]", b["expr"])[-1] == verdict[1]
            if verdict[1] != fact and not counted:
                out.append(f"{where}: says *{verdict[1]}*, the fact {b['source']}:{b['expr']} is {fact!r}")
            continue
        if number is None:
            out.append(f"{where}: a binding follows no number or verdict")
            continue
        if not _matches(number["digits"], number["sign"], fact):
            out.append(f"{where}: says {number['sign']}{number['digits']}, the fact {b['source']}:{b['expr']} "
                       f"is {fact!r}")
    if strict:
        masked = IDENTIFIERS.sub(lambda m: " " * len(m[0]), text)
        for n in NUMBER.finditer(masked):
            if n.start("digits") not in bound_at:
                out.append(f"…{text[max(0, n.start() - 40):n.end()]}: {n['digits']} is bound to no fact")
        for v in VERDICT.finditer(masked):
            if not text.startswith("<!--=", v.end()):
                out.append(f"…{text[max(0, v.start() - 40):v.end()]}: *{v['word']}* is bound to no fact")
        for a in re.finditer(r"\*\*(?P<word>Yes|No|Not shown|In part|Mixed)(?=[.,:;])", masked):
            if not text.startswith("<!--=", a.end()):
                out.append(f"…{text[max(0, a.start() - 40):a.end()]}: the answer **{a['word']}** is bound to no "
                           "answer fact")
    return out


def _answer_problems(word: str, fact: Any, name: str) -> list[str]:
    """What is wrong with the bold answer ``word`` bound to the answer fact ``name``."""
    from jaxapf.stats import answer

    if not (isinstance(fact, dict) and isinstance(fact.get("word"), str) and isinstance(fact.get("verdicts"), dict)):
        return [f"the answer is bound to {name}, which is no answer fact (word and verdicts)"]
    out = [] if word == fact["word"] else [f"answers **{word}**, the fact {name} is {fact['word']!r}"]
    try:
        derived = answer(list(fact["verdicts"].values()))
    except ValueError as err:
        return out + [f"{name}: {err}"]
    if derived != fact["word"]:
        out.append(f"{name} answers {fact['word']!r} where its verdicts allow {derived!r}")
    return out


def mutations(text: str) -> Iterator[tuple[str, str]]:
    """``(what, mutated text)``: each bound number with its last digit one up and one down, and each bound
    verdict word swapped for every other one."""
    for b in BINDING.finditer(text):
        before = text[max(0, b.start() - 80):b.start()]
        offset = b.start() - len(before)
        said = ANSWER.search(before)
        if said is not None:
            at, end = offset + said.start("word"), offset + said.end("word")
            for other in ("Yes", "No", "Not shown", "In part", "Mixed"):
                if other != said["word"]:
                    yield (f"**{said['word']}** -> **{other}**", text[:at] + other + text[end:])
            continue
        verdict = re.search(r"\*(\w+)\*$", before)
        if verdict is not None:
            at, end = offset + verdict.start(1), offset + verdict.end(1)
            for other in VERDICTS:
                if other != verdict[1]:
                    yield (f"*{verdict[1]}* -> *{other}*", text[:at] + other + text[end:])
            continue
        number = re.search(r"(?<![\w.])\d[\d,]*(?:\.\d+)?$", before)
        if number is None:
            continue
        digits, at, end = number[0], offset + number.start(), offset + number.end()
        for step in (1, -1):
            changed = _shift(digits, step)
            if changed is not None:
                yield (f"{digits} -> {changed}", text[:at] + changed + text[end:])


def _shift(digits: str, step: int) -> str | None:
    """``digits`` with its last digit moved by ``step`` (carrying: 9 + 1 -> 10, 10 - 1 -> 09 -> 9);
    None where that would go below zero."""
    plain = digits.replace(",", "")
    decimals = len(plain.partition(".")[2])
    units = int(plain.replace(".", "")) + step
    if units < 0:
        return None
    text = f"{units / 10 ** decimals:.{decimals}f}" if decimals else str(units)
    return f"{int(text):,}" if "," in digits and not decimals else text


def suggest(path: pathlib.Path, sources: list[str]) -> Iterator[str]:
    """For each unbound number of ``path``: the keys of ``sources`` whose value it is."""
    text = path.read_text()

    def leaves(x: Any, prefix: str = "") -> Iterator[tuple[str, float]]:
        if isinstance(x, dict):
            for k, v in x.items():
                yield from leaves(v, f"{prefix}.{k}" if prefix else str(k))
        elif isinstance(x, list):
            for i, v in enumerate(x):
                yield from leaves(v, f"{prefix}.{i}" if prefix else str(i))
        elif isinstance(x, (int, float)) and not isinstance(x, bool):
            yield prefix, float(x)
    facts = [(s, k, v) for s in sources for k, v in leaves(_source(s))]
    for problem in problems(text):
        if not problem.endswith("is bound to no fact") or problem.startswith("…") is False:
            continue
        written = problem.rsplit(": ", 1)[1].split(" is bound")[0]
        found = [f"{s}:{k}{t}" for s, k, v in facts for t, x in (("", v), ("×100", 100 * v))
                 if not written.startswith("*") and _matches(written, "", x)]
        yield f"{problem.split(': ')[0]} {written}  ->  {', '.join(found[:6]) or 'no fact of these sources'}"


if __name__ == "__main__":
    usage = ("usage: python tests/bindings.py check FILE...   (every number bound, every binding its fact)\n"
             "       python tests/bindings.py suggest FILE [SOURCE ...]   "
             "(SOURCE: bench/NAME, study/FOLDER or scorecard/VERSION)")
    if len(sys.argv) < 3 or sys.argv[1] not in ("check", "suggest"):
        sys.exit(usage)
    if sys.argv[1] == "check":
        found = [f"{name}: {p}" for name in sys.argv[2:] for p in problems(pathlib.Path(name).read_text())]
        print("\n".join(found) or "every number bound to its fact")
        sys.exit(1 if found else 0)
    for line in suggest(pathlib.Path(sys.argv[2]), sys.argv[3:]):
        print(line)
