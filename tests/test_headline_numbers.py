"""The headline numbers cannot fall unnoticed: JSAR's and JSAR-Re's mean AUC in one pass over the shared
set, and JSAR-Re's re-acquisition and false re-initialisation rates in the long-term protocol (seed 0),
each against a bound a margin below (above, for the false re-initialisations) the number documented in
docs/results-tracker.md's headline table, which this test reads: the document and the test cannot disagree.

Runs what `python -m jsar.eval DATA --trackers jsar,jsar-re` and `python -m jsar.eval DATA --longterm
--seed 0 --trackers jsar-re` run, through jsar.eval.evaluate, on the shared set (JSAR_DATA_ROOT).
"""
from __future__ import annotations

import re
from pathlib import Path

import pytest

from jsar.eval import dataset, evaluate, longterm

RESULTS_DOC = Path(__file__).resolve().parents[1] / "docs" / "results-tracker.md"
HEADLINE_HEADING = "## Headline results"
SHARED_SET = "shared"  # the table's name for the set these tests run on

# Margins between the documented number and the bound: they absorb harmless changes (e.g. float order,
# another CPU's kernels), not a regression.
AUC_MARGIN = 0.009  # one-pass mean AUC below the documented value
REACQUIRED_MARGIN_EVENTS = 1  # long-term events re-acquired below the documented count
FALSE_REINIT_MARGIN_FRAMES = 11  # false re-initialisations (absent frames) above the documented count

SHARED_SET_SEQUENCES = 7  # the bounds hold for the set they were measured on
SHARED_SET_FRAMES = 1317
LONGTERM_SEED = 0

COUNT = re.compile(r"\(\s*(\d+)\s*/\s*(\d+)\s*\)")  # "0.656 (21 / 32)" -> 21, 32


def headline_table(text: str) -> dict[tuple[str, str], dict[str, str]]:
    """The headline table's rows {(set, tracker): {column header: cell}} from the results document's text."""
    start = text.find("\n" + HEADLINE_HEADING)
    if start < 0:
        raise ValueError(f"no {HEADLINE_HEADING!r} section in {RESULTS_DOC.name}")
    lines: list[str] = []  # the first table after the heading: its contiguous "|" lines
    for line in text[start + 1:].splitlines()[1:]:
        if line.startswith("#"):
            break
        if line.startswith("|"):
            lines.append(line.strip())
        elif lines:
            break
    if len(lines) < 3:
        raise ValueError(f"no table under {HEADLINE_HEADING!r} in {RESULTS_DOC.name}")
    header = [cell.strip() for cell in lines[0].strip("|").split("|")]
    rows: dict[tuple[str, str], dict[str, str]] = {}
    for line in lines[2:]:  # lines[1] is the |---| rule
        cells = [cell.strip().strip("*") for cell in line.strip("|").split("|")]
        if len(cells) != len(header):
            raise ValueError(f"headline row {line!r} has {len(cells)} cells, the header {len(header)}")
        row = dict(zip(header, cells))
        rows[(row["set"], row["tracker"])] = row
    return rows


def documented(tracker: str) -> dict[str, str]:
    """The headline table's shared-set row of `tracker`."""
    rows = headline_table(RESULTS_DOC.read_text(encoding="utf-8"))
    if (SHARED_SET, tracker) not in rows:
        raise ValueError(f"{RESULTS_DOC.name}'s headline table has no {SHARED_SET!r} row for {tracker!r}")
    return rows[(SHARED_SET, tracker)]


def column(row: dict[str, str], prefix: str) -> str:
    """The cell of the one column whose header starts with `prefix`."""
    matches = [name for name in row if name.startswith(prefix)]
    if len(matches) != 1:
        raise ValueError(f"headline table: {len(matches)} columns start with {prefix!r}: {list(row)}")
    return row[matches[0]]


def documented_auc(tracker: str) -> float:
    """One-pass mean AUC on the shared set, as documented."""
    return float(column(documented(tracker), "one pass: AUC"))


def documented_count(tracker: str, prefix: str) -> tuple[int, int]:
    """(count, out of) from a cell written "rate (count / total)", e.g. long-term events re-acquired."""
    cell = column(documented(tracker), prefix)
    match = COUNT.search(cell)
    if not match:
        raise ValueError(f"headline table, {tracker} {prefix!r}: {cell!r} is not 'rate (count / total)'")
    return int(match.group(1)), int(match.group(2))


def test_the_headline_table_documents_the_bounded_numbers() -> None:
    """Runs without data: the document's shared rows parse, with counts whose rates match their cells."""
    for tracker in ("jsar", "jsar-re"):
        assert 0.0 < documented_auc(tracker) < 1.0
    for prefix in ("long-term seed 0: re-acquired", "long-term seed 0: false"):
        count, total = documented_count("jsar-re", prefix)
        rate = float(column(documented("jsar-re"), prefix).split()[0])
        assert 0 <= count <= total and total > 0
        assert rate == pytest.approx(count / total, abs=0.0015), (prefix, rate, count, total)


@pytest.fixture(scope="module")
def shared_set(data_root) -> list[dataset.Sequence]:
    """The shared set's sequences; skip when JSAR_DATA_ROOT holds another set (the bounds are its own)."""
    sequences = [dataset.load_sequence(folder) for folder in dataset.discover_sequences(data_root)]
    frames = sum(len(s) for s in sequences)
    if (len(sequences), frames) != (SHARED_SET_SEQUENCES, SHARED_SET_FRAMES):
        pytest.skip(f"the headline bounds were measured on the shared set ({SHARED_SET_SEQUENCES} sequences, "
                    f"{SHARED_SET_FRAMES} frames); JSAR_DATA_ROOT={data_root} holds {len(sequences)} sequences, "
                    f"{frames} frames")
    return sequences


@pytest.fixture(scope="module")
def one_pass(shared_set) -> dict[str, dict[str, object]]:
    """Per tracker: the one-pass summary row (mean AUC, errors, ...)."""
    return evaluate.evaluate(shared_set, ["jsar", "jsar-re"])["summary"]


@pytest.fixture(scope="module")
def longterm_seed0(shared_set) -> dict[str, object]:
    """JSAR-Re's long-term summary row (its "longterm" rates, errors, ...) for seed 0, every event kind."""
    return evaluate.evaluate_longterm(shared_set, ["jsar-re"], list(longterm.EVENT_KINDS), longterm.DEFAULT_LENGTHS,
                                      seed=LONGTERM_SEED)["summary"]["jsar-re"]


@pytest.mark.parametrize("tracker", ["jsar", "jsar-re"])
@pytest.mark.slow
def test_one_pass_mean_auc_stays_above_its_floor(one_pass, tracker: str) -> None:
    row = one_pass[tracker]
    assert not row["errors"], row["errors"]
    auc, listed = float(row["auc"]), documented_auc(tracker)
    floor = listed - AUC_MARGIN
    assert auc >= floor, f"{tracker}: mean AUC {auc:.4f} < {floor:.4f} (documented {listed:.4f} - {AUC_MARGIN})"


@pytest.mark.slow
def test_longterm_reacquisition_floor_and_false_reinit_ceiling(longterm_seed0) -> None:
    row = longterm_seed0
    assert not row["errors"], row["errors"]
    lt = row["longterm"]
    assert lt["n_events"] > 0 and lt["absent_frames"] > 0, lt
    reacquired, false_reinit = float(lt["reacquisition_rate"]), float(lt["false_reinit_rate"])
    events_listed, events = documented_count("jsar-re", "long-term seed 0: re-acquired")
    false_listed, absent = documented_count("jsar-re", "long-term seed 0: false")
    assert (lt["n_events"], lt["absent_frames"]) == (events, absent), \
        f"this run has {lt['n_events']} events and {lt['absent_frames']} absent frames; the table {events} and {absent}"
    floor = (events_listed - REACQUIRED_MARGIN_EVENTS) / events
    ceiling = (false_listed + FALSE_REINIT_MARGIN_FRAMES) / absent
    assert reacquired >= floor, \
        f"re-acquisition rate {reacquired:.4f} of {events} events < {floor:.4f} (documented {events_listed} / " \
        f"{events} less {REACQUIRED_MARGIN_EVENTS})"
    assert false_reinit <= ceiling, \
        f"false re-initialisation rate {false_reinit:.4f} of {absent} absent frames > {ceiling:.4f} (documented " \
        f"{false_listed} / {absent} plus {FALSE_REINIT_MARGIN_FRAMES})"
