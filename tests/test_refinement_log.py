"""The refinement log (``refinement_log.csv``) and the refinement times in the element output:
every refined (cell, interface) once per state, at the time it refined, with the indicator
that asked."""

import csv
import math

import numpy as np
import pytest
from helpers import run_quietly
from test_restart import late_refinement

from fenics_adaptive.adaptivity.events import Reason, _reasons_of, note
from fenics_adaptive.settings.kinds import InterfaceState


def test_the_first_indicator_to_ask_keeps_its_reason():
    reasons = {}
    note(reasons, [(3, 2, InterfaceState.STRONG)], "interface_stress", [1.2])
    note(reasons, [(3, 2, InterfaceState.STRONG), (4, 2, InterfaceState.STRONG)], "spread")
    assert reasons[(3, 2, InterfaceState.STRONG)] == Reason("interface_stress", 1.2)
    assert reasons[(4, 2, InterfaceState.STRONG)].indicator == "spread"
    # a strong request on an unrefined interface also explains its weak step
    pairs = np.array([[3, 2], [5, 1]])
    weak = _reasons_of(pairs, (InterfaceState.WEAK, InterfaceState.STRONG), reasons)
    assert weak[0] == Reason("interface_stress", 1.2)
    assert weak[1].indicator == "unknown" and math.isnan(weak[1].value)


def read_log(path):
    with open(path, newline="") as file:
        return list(csv.DictReader(file))


@pytest.mark.slow
def test_log_lists_each_refinement_once_with_its_time_and_reason(tmp_path):
    data = late_refinement(5.0e-5)
    data["output"]["fields_interval"] = 5.0e-5
    summary = run_quietly(data, tmp_path)
    rows = read_log(tmp_path / "refinement_log.csv")
    key = [(r["cell"], r["interface"], r["state"]) for r in rows]
    assert len(key) == len(set(key))  # once per (cell, interface, state)
    n_cells = data["mesh"]["nx"] * data["mesh"]["ny"]
    assert {r["indicator"] for r in rows} == {"manual"}  # [interfaces] initial = "none"
    # the two [[refinement]] entries over x >= 5 mm: weak at 2e-5 s (2, 4, 6), strong at
    # 4e-5 s (2, 6)
    half = n_cells // 2
    entries = (("weak", 2.0e-5, {"2", "4", "6"}), ("strong", 4.0e-5, {"2", "6"}))
    for state, time, interfaces in entries:
        these = [r for r in rows if r["state"] == state]
        assert len(these) == len(interfaces) * half
        # at the first step on or after the entry's time
        (when,) = {float(r["time_s"]) for r in these}
        assert time <= when < time + 1.01 * data["solver"]["time_step"]
        assert {r["interface"] for r in these} == interfaces
        assert min(float(r["x_mm"]) for r in these) >= 5.0
    assert summary["refinement_events"] == 2
    # the element output carries the same times as cell fields
    last = sorted((tmp_path / "elements").glob("*"))[-1].read_bytes()
    for name in ("weak_time_2", "strong_time_2", "weak_time_4", "strong_time_6"):
        assert name.encode() in last, name


def test_the_initial_refinement_is_logged_at_time_zero(tmp_path):
    data = late_refinement(2.0e-7)
    data["interfaces"]["initial"] = "strong"
    del data["refinement"]
    run_quietly(data, tmp_path)
    rows = read_log(tmp_path / "refinement_log.csv")
    n_cells = data["mesh"]["nx"] * data["mesh"]["ny"]
    # refine = [4] weak, delaminate = [2, 6] weak then strong, all at t = 0
    assert {(r["indicator"], float(r["time_s"])) for r in rows} == {("initial", 0.0)}
    expected = {"2": {"weak", "strong"}, "4": {"weak"}, "6": {"weak", "strong"}}
    for interface, states in expected.items():
        assert sorted(r["cell"] for r in rows if r["interface"] == interface) == sorted(
            [str(c) for c in range(n_cells)] * len(states)
        )


def test_a_restart_keeps_the_log_rows_its_state_holds(tmp_path):
    """A checkpoint taken before its step's evaluation (periodic, or a stop acted on at a
    poll) refines at its time t again when the restart evaluates it: the log rows at t, which
    a run killed after the checkpoint wrote, are not kept (they were, and the refinement at t
    was logged twice); a state taken after its evaluation keeps them."""
    from fenics_adaptive.io.refinement_log import COLUMNS
    from fenics_adaptive.io.refinement_log import read_log as kept_rows

    path = tmp_path / "refinement_log.csv"
    with open(path, "w", newline="") as file:
        writer = csv.writer(file)
        writer.writerow(COLUMNS)
        for t in (1e-6, 2e-6, 3e-6):
            writer.writerow([t, 0, 0.5, 0.5, 2, "strong", "manual", "nan"])
    assert [r[0] for r in kept_rows(path, 2e-6)] == [1e-6, 2e-6]
    assert [r[0] for r in kept_rows(path, 2e-6, inclusive=False)] == [1e-6]


def test_what_the_run_ends_before_is_warned_of():
    """The late-refinement TCB ended at 3e-5 s: its strong entry at 4e-5 s never acts, and
    fields every 5e-5 s give the frame at t = 0 alone. Ended at 1e-4 s, nothing is warned of;
    an entry made due by a probe displacement neither."""
    from fenics_adaptive.settings.config import parse_config
    from fenics_adaptive.simulation import Simulation

    whole = late_refinement(1.0e-4)
    whole["output"]["fields_interval"] = 5.0e-5
    assert Simulation(parse_config(whole)).warnings == []
    short = late_refinement(3.0e-5)
    short["output"]["fields_interval"] = 5.0e-5
    warnings = Simulation(parse_config(short)).warnings
    assert len(warnings) == 2, warnings
    fields, late = warnings
    assert "fields_interval = 5e-05 s is longer than solver.end_time = 3e-05 s" in fields
    assert "written at t = 0 alone" in fields
    assert "[[refinement]] 2 is due at t = 4e-05 s, after solver.end_time" in late
    short["refinement"][1] |= {"displacement": 0.01}
    del short["refinement"][1]["time"]
    assert Simulation(parse_config(short)).warnings == [fields]
