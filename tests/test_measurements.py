"""Measurement format: loading, validation errors, messy real logs, MCAP conversion, noise floor."""

from __future__ import annotations

import dataclasses

from collections import Counter
from pathlib import Path

import numpy as np
import pytest
import yaml
from hypothesis import given, settings
from hypothesis import strategies as st

from sim2real.measurements.bags import mcap_to_run
from sim2real.errors import InputError
from sim2real.measurements import (
    IncompleteRows,
    noise_floor_of,
    load_measurement_list,
    load_prepared_runs,
    load_run,
    prepare_run,
    Run,
    RunMeta,
    SpikeRecord,
    write_run,
)

JOINTS = ["panda_joint1", "panda_joint2"]
META = {"robot": "panda", "source": "real", "control_mode": "torque"}


def motion(t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    q = np.column_stack([0.5 * np.sin(1.3 * t), -0.3 + 0.4 * np.cos(0.9 * t)])
    qd = np.column_stack([0.65 * np.cos(1.3 * t), -0.36 * np.sin(0.9 * t)])
    qdd = np.column_stack([-0.845 * np.sin(1.3 * t), -0.324 * np.cos(0.9 * t)])
    return q, qd, qdd


def write_csv(path: Path, header: list[str], rows: list[list[float]], meta: dict | None = None) -> Path:
    """A run written by hand: plain text lines, the way a user exports a log."""
    lines = [",".join(header)] + [",".join(repr(float(v)) for v in row) for row in rows]
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    path.with_suffix(".yaml").write_text(yaml.safe_dump(meta or META), encoding="utf-8")
    return path


def good_rows(n: int = 3000, dt: float = 0.001) -> tuple[list[str], list[list[float]]]:
    t = np.arange(n) * dt
    q, _, qdd = motion(t)
    tau = 2.0 * qdd + 0.1
    header = ["time"] + [f"q.{j}" for j in JOINTS] + [f"tau.{j}" for j in JOINTS]
    return header, [[t[k], *q[k], *tau[k]] for k in range(n)]


def test_hand_written_csv_run_loads_and_prepares(tmp_path):
    header, rows = good_rows()
    run = load_run(write_csv(tmp_path / "log.csv", header, rows), known_joints=JOINTS + ["panda_joint3"])
    assert run.joint_names == JOINTS and run.qd is None and run.tau_cmd is None
    prepared = prepare_run(run)
    assert prepared.torque_source == "tau"
    _, qd, qdd = motion(prepared.time)
    assert np.max(np.abs(prepared.qd - qd)) < 1e-3
    assert np.max(np.abs(prepared.qdd - qdd)) < 0.03  # filter edges: ~1% of the peak
    assert prepared.filter.cutoff_hz == 10.0 and "sosfiltfilt" in prepared.filter.type


def test_messy_real_log_irregular_stamps_repeats_no_commands_no_qd(tmp_path):
    rng = np.random.default_rng(0)
    steps = rng.uniform(0.0007, 0.009, size=1500)
    steps[::50] = 0.009
    t = np.concatenate([[0.0], np.cumsum(steps)])
    q, _, qdd = motion(t)
    repeat = rng.random(t.size) < 0.2  # logger faster than the state: positions repeat
    for k in np.flatnonzero(repeat):
        if k > 0:
            q[k] = q[k - 1]
    tau = 2.0 * qdd + 0.01 * rng.standard_normal(qdd.shape)
    header = ["time"] + [f"q.{j}" for j in JOINTS] + [f"tau.{j}" for j in JOINTS]
    path = write_csv(tmp_path / "messy.csv", header, [[t[k], *q[k], *tau[k]] for k in range(t.size)])
    prepared = prepare_run(load_run(path), sample_rate_hz=1000.0)
    assert prepared.filter.repeated_samples_dropped > 100
    assert prepared.filter.raw_step_ms.max == pytest.approx(9.0, rel=1e-6)
    assert np.allclose(np.diff(prepared.time), 1e-3)
    _, qd_true, _ = motion(prepared.time)
    assert np.sqrt(np.mean((prepared.qd - qd_true) ** 2)) < 0.02
    assert prepared.tau_cmd is None


@pytest.mark.parametrize(
    ("mutate", "expected"),
    [
        (lambda h, r: r[37].__setitem__(1, float("inf")), ["q.panda_joint1", "row 37", "line 39", "infinite"]),
        (lambda h, r: [row.__setitem__(3, float("nan")) for row in r[::3]], ["tau.panda_joint1", "empty in 1000 of 3000",
                                                                            "row 0 (line 2)", "merge_asof"]),
        (lambda h, r: [r[k].__setitem__(1 + (k // 4) % 4, float("nan")) for k in range(5, 3000, 4)],
         ["row 5 (line 7) and 748 more", "749 of 3000 rows", "merge_asof"]),
        (lambda h, r: r[100].__setitem__(0, r[99][0]), ["column 'time'", "row 100", "does not increase", " s then "]),
        (lambda h, r: [h.__setitem__(k, h[k].replace("panda_joint1", "elbow")) for k in (1, 3)], ["q.elbow", "unknown joint"]),
        (lambda h, r: h.__setitem__(1, "q.elbow"), ["tau.<joint>", "missing for elbow; without q for panda_joint1"]),
        (lambda h, r: [row.__setitem__(1, row[1] * 180 / np.pi + 90.0) for row in r], ["q.panda_joint1", "degrees"]),
        (lambda h, r: r.__delitem__(slice(500, None)), ["too short"]),
        (lambda h, r: h.__setitem__(4, "velocity.panda_joint2"), ["velocity.panda_joint2", "not part of"]),
        (lambda h, r: [row.__setitem__(4, 0.0) for row in r], ["tau.panda_joint2", "same value (0) in every row",
                                                              "measured nothing", "leave out every tau.<joint>"]),
    ],
    ids=["infinite", "column_mostly_empty", "rows_mostly_incomplete", "time_not_increasing", "unknown_joint", "renamed_in_one_column", "degrees", "too_short", "bad_column",
         "dead_torque_channel"],
)
def test_bad_input_names_file_column_row(tmp_path, mutate, expected):
    header, rows = good_rows()
    mutate(header, rows)
    path = write_csv(tmp_path / "bad.csv", header, rows)
    with pytest.raises(InputError) as info:
        load_run(path, known_joints=JOINTS)
    message = str(info.value)
    assert "bad.csv" in message and "Fix:" in message
    assert "np." not in message  # numbers as the user wrote them, not numpy reprs (np.float64(1.99))
    for part in expected:
        assert part in message


def test_degrees_detected_from_limits_for_small_motions(tmp_path):
    header, rows = good_rows()
    for row in rows:
        row[2] = np.rad2deg(row[2]) / 10  # within +-7 "rad" but outside joint 2's range
    path = write_csv(tmp_path / "deg.csv", header, rows)
    with pytest.raises(InputError, match="looks like degrees"):
        load_run(path, JOINTS, position_limits={"panda_joint1": (-2.9, 2.9), "panda_joint2": (-1.76, 1.76)})


def test_missing_metadata_partial_signals_and_no_torque(tmp_path):
    header, rows = good_rows()
    path = write_csv(tmp_path / "a.csv", header, rows)
    path.with_suffix(".yaml").unlink()
    with pytest.raises(InputError, match="metadata"):
        load_run(path)
    path = write_csv(tmp_path / "b.csv", header[:4], [r[:4] for r in rows])
    with pytest.raises(InputError, match="some joints only"):
        load_run(path)
    path = write_csv(tmp_path / "c.csv", header[:3], [r[:3] for r in rows])
    with pytest.raises(InputError, match="no torque"):
        load_run(path)
    path = write_csv(tmp_path / "d.csv", header, rows, meta={**META, "source": "lab"})
    with pytest.raises(InputError, match="source"):
        load_run(path)


def test_parquet_roundtrip_and_tau_cmd_fallback(tmp_path):
    t = np.arange(2000) * 0.001
    q, _, qdd = motion(t)
    write_run(tmp_path / "r.parquet", t, JOINTS, {"q": q, "tau_cmd": qdd}, META)
    run = load_run(tmp_path / "r.parquet")
    assert run.tau is None and np.array_equal(run.tau_cmd, qdd)
    assert prepare_run(run).torque_source == "tau_cmd"


def test_the_actuator_links_noise_floor_is_prepared_with_the_run_and_read_back(tmp_path):
    """A run that logs tau and tau_cmd carries the actuator link's floor from the rule that prepares it (what tau
    has that no filter of the command explains), through the prepared runs' file; one without it gets it computed."""
    from sim2real.measurements import command_floor_of
    from sim2real.measurements import (
        MeasurementEntry, RunSet, command_white_noise, read_prepared_runs, with_command_floor, write_prepared_runs,
    )

    rng = np.random.default_rng(5)
    t = np.arange(6000) * 0.001
    q, _, qdd = motion(t)
    tau_cmd = 2.0 * qdd + rng.normal(scale=0.3, size=qdd.shape)
    tau = 0.9 * np.roll(tau_cmd, 4, axis=0) + rng.normal(scale=0.05, size=qdd.shape)  # a gain, a delay, noise
    write_run(tmp_path / "r.parquet", t, JOINTS, {"q": q, "tau": tau, "tau_cmd": tau_cmd}, META)
    run = with_command_floor(prepare_run(load_run(tmp_path / "r.parquet")))
    expected = command_white_noise(run.tau, run.tau_cmd, run.dt)
    assert run.command_torque_sigma.shape == (len(JOINTS),) and np.array_equal(run.command_torque_sigma, expected)
    assert np.all((expected > 0.02) & (expected < 0.2))  # the sensor's noise (0.05 N*m, differenced and robust)
    write_prepared_runs(tmp_path / "runs.npz",
                        RunSet((dataclasses.replace(run, entry=MeasurementEntry("r", Path("r.parquet"), "fit")),), {}))
    back = read_prepared_runs(tmp_path / "runs.npz")[0]
    assert np.array_equal(command_floor_of(back), expected)
    assert np.array_equal(command_floor_of(dataclasses.replace(back, command_torque_sigma=np.zeros(0))), expected)
    only_commands = with_command_floor(prepare_run(dataclasses.replace(load_run(tmp_path / "r.parquet"), tau=None)))
    assert only_commands.command_torque_sigma.size == 0


def test_a_long_logs_actuator_floor_is_summed_chunk_by_chunk(monkeypatch):
    """Beyond a chunk of rows the lagged regression's products are summed a chunk at a time (never the whole lagged
    design, which numpy would copy twice: 1 GB on a 10-minute log): the same floor but for round-off."""
    from sim2real import blas
    from sim2real.measurements import command_white_noise

    rng = np.random.default_rng(8)
    t = np.arange(6000) * 0.001
    tau_cmd = 2.0 * motion(t)[2] + rng.normal(scale=0.3, size=(len(t), len(JOINTS)))
    tau = 0.9 * np.roll(tau_cmd, 4, axis=0) + rng.normal(scale=0.05, size=tau_cmd.shape)
    whole = command_white_noise(tau, tau_cmd, 0.001)
    monkeypatch.setattr(blas, "CHUNK_ROWS", 1000)  # six chunks and a part
    chunked = command_white_noise(tau, tau_cmd, 0.001)
    assert np.allclose(chunked, whole, rtol=1e-9, atol=0.0)  # the sums' order differs, not the floor
    assert np.all((whole > 0.02) & (whole < 0.2))


def test_the_actuator_floor_is_the_same_bytes_whatever_the_callers_blas_threads():
    """The rule prepares runs with BLAS on one thread; a caller with more gets the same floor to the bit (the
    lagged regression's products split among threads would move its last digits)."""
    from threadpoolctl import threadpool_limits

    from sim2real.measurements import command_white_noise

    rng = np.random.default_rng(8)
    tau_cmd = np.cumsum(rng.normal(size=(20000, 3)), axis=0) * 0.01 + rng.normal(scale=0.3, size=(20000, 3))
    tau = 0.9 * np.roll(tau_cmd, 4, axis=0) + rng.normal(scale=0.05, size=tau_cmd.shape)
    floors = []
    for threads in (1, 2):
        with threadpool_limits(limits=threads, user_api="blas"):
            floors.append(command_white_noise(tau, tau_cmd, 0.001))
    assert np.array_equal(floors[0], floors[1])


def test_noise_floor_matches_white_torque_noise(tmp_path):
    rng = np.random.default_rng(3)
    t = np.arange(8000) * 0.001
    q, _, qdd = motion(t)
    sigma = np.array([0.05, 0.2])
    tau = 3.0 * qdd + sigma * rng.standard_normal(qdd.shape)
    write_run(tmp_path / "n.parquet", t, JOINTS, {"q": q, "tau": tau}, META)
    floor = noise_floor_of(prepare_run(load_run(tmp_path / "n.parquet")))
    assert np.allclose(floor, sigma, rtol=0.1)


def test_measurement_list_roles_and_duplicates(tmp_path):
    path = tmp_path / "m.yaml"
    path.write_text(yaml.safe_dump({"runs": [{"name": "a", "path": "x.csv", "role": "fit"},
                                             {"name": "b", "path": "y.parquet", "role": "holdout"}]}))
    entries = load_measurement_list(path)
    assert [(e.name, e.role) for e in entries] == [("a", "fit"), ("b", "holdout")]
    path.write_text(yaml.safe_dump({"runs": [{"name": "a", "path": "x.csv", "role": "fit"},
                                             {"name": "a", "path": "y.csv", "role": "test"}]}))
    with pytest.raises(InputError, match="role"):
        load_measurement_list(path)


def test_prepared_runs_follow_the_list_and_its_filter_and_share_joints(tmp_path):
    header, rows = good_rows()
    write_csv(tmp_path / "a.csv", header, rows)
    write_csv(tmp_path / "b.csv", header, rows)
    listing = tmp_path / "m.yaml"
    listing.write_text(yaml.safe_dump({"runs": [{"name": "one", "path": "a.csv", "role": "fit"},
                                                {"name": "two", "path": "b.csv", "role": "holdout"}],
                                       "filter": {"cutoff_hz": 8.0}}))
    prepared = load_prepared_runs(listing, JOINTS, root=tmp_path)
    assert [e.name for e in prepared.entries] == [p.name for p in prepared] == ["one", "two"]
    assert [p.name for p in prepared.fit] == ["one"] and [p.name for p in prepared.holdout] == ["two"]
    assert [p.role for p in prepared] == ["fit", "holdout"]
    assert prepared.settings["cutoff_hz"] == 8.0 and all(p.filter.cutoff_hz == 8.0 for p in prepared)
    # a run that logs other joints than the first one is named, with the joints to log
    write_csv(tmp_path / "b.csv", [h.replace("panda_joint2", "panda_joint3") for h in header], rows)
    with pytest.raises(InputError, match=r"b\.csv.*joints differ.*panda_joint1, panda_joint2"):
        load_prepared_runs(listing, [*JOINTS, "panda_joint3"], root=tmp_path)


def _listing(tmp_path: Path, header: list[str], rows: list[list[float]], **settings: object) -> Path:
    write_csv(tmp_path / "a.csv", header, rows)
    listing = tmp_path / "m.yaml"
    listing.write_text(yaml.safe_dump({"runs": [{"name": "one", "path": "a.csv", "role": "fit"}], **settings}))
    return listing


def test_a_log_with_lost_stretches_is_prepared_piece_by_piece_never_across_them(tmp_path):
    """A logger that loses 0.3 s twice: interpolated across, the lost stretches become straight lines of q whose
    second derivative is no acceleration the arm made. Split at them, every prepared sample is one the log holds on
    both sides, and the accelerations are as good as a log without loss; the pieces keep the run's entry."""
    header, rows = good_rows(n=9000)
    lost = [r for r in rows if not (2.0 <= r[0] < 2.3 or 5.5 <= r[0] < 5.8)]
    prepared = load_prepared_runs(_listing(tmp_path, header, lost), JOINTS, root=tmp_path)
    assert [p.name for p in prepared] == ["one#1", "one#2", "one#3"] and all(e.name == "one" for e in prepared.entries)
    assert prepared.fit == prepared.runs and not prepared.holdout  # each piece keeps the run's role
    for piece in prepared:
        assert not np.any((piece.time > 1.999) & (piece.time < 2.3)) and not np.any((piece.time > 5.499) & (piece.time < 5.8))
        _, qd, qdd = motion(piece.time)
        assert np.max(np.abs(piece.qdd - qdd)) < 0.03  # as a log without loss (the test above)
        record = piece.filter.gaps
        assert record.run == "one" and record.max_step_s == pytest.approx(0.02)
        assert [round(g.after_s, 3) for g in record.gaps] == [1.999, 5.499]
        assert [g.lost_s for g in record.gaps] == pytest.approx([0.301, 0.301])
    # The same log interpolated across its lost stretches (a threshold above them): the acceleration there is wrong.
    across = load_prepared_runs(_listing(tmp_path, header, lost, gaps={"max_step_s": 1.0}), JOINTS, root=tmp_path)
    (whole,) = across
    _, _, qdd = motion(whole.time)
    assert whole.name == "one" and whole.filter.gaps is None
    assert np.max(np.abs(whole.qdd - qdd)) > 0.3


def test_rows_with_an_empty_cell_are_samples_the_logger_lost(tmp_path):
    """Blank cells in a user's export (a torque that missed a few samples, a stretch of one channel lost): each such
    row is dropped, and the run is prepared exactly as if the logger had not written those rows at all, split where
    they make a stretch longer than the filter can bridge; the prepared runs and gap.md say how many. Errors after
    the drop still name the file's own rows."""
    header, rows = good_rows(n=9000)
    rng = np.random.default_rng(3)
    blank = {int(k): int(c) for k, c in zip(rng.choice(9000, 40, replace=False), rng.integers(1, 5, 40))}
    blank.update({k: 4 for k in range(2000, 2300)})  # tau.panda_joint2 lost for 0.3 s
    path = tmp_path / "a.csv"
    path.write_text("\n".join([",".join(header)] + [
        ",".join("" if blank.get(k) == c else repr(float(v)) for c, v in enumerate(row)) for k, row in enumerate(rows)])
        + "\n")
    path.with_suffix(".yaml").write_text(yaml.safe_dump(META))
    listing = tmp_path / "m.yaml"
    listing.write_text(yaml.safe_dump({"runs": [{"name": "one", "path": "a.csv", "role": "fit"}]}))
    prepared = load_prepared_runs(listing, JOINTS, root=tmp_path)
    (tmp_path / "lost").mkdir()
    expected = load_prepared_runs(_listing(tmp_path / "lost", header, [r for k, r in enumerate(rows) if k not in blank]),
                                        JOINTS, root=tmp_path / "lost")
    assert [p.name for p in prepared] == [p.name for p in expected] == ["one#1", "one#2"]
    for got, want in zip(prepared, expected, strict=True):
        for signal in ("time", "q", "qd", "qdd", "tau"):
            assert np.array_equal(getattr(got, signal), getattr(want, signal)), signal
        first = min(blank)
        assert got.filter.incomplete_rows == IncompleteRows(dropped=len(blank), of=9000,
                                                            first_row=f"row {first} (line {first + 2})", run="one")
        assert got.filter.as_document()["incomplete_rows"] == {"run": "one", "dropped": len(blank), "of": 9000,
                                                               "first_row": f"row {first} (line {first + 2})"}
        assert dataclasses.replace(got.filter, incomplete_rows=None) == want.filter
    from sim2real.report.runs_section import _incomplete_lines
    assert f"- one: {len(blank)} of 9000 rows (3.8%), the first row {first}" in "\n".join(
        _incomplete_lines([{"filter": p.filter.as_document()} for p in prepared]))
    # a position in degrees after the dropped rows: named at its row of the file
    header, rows = good_rows()
    rows[10][1] = float("nan")
    rows[2500][1] = 400.0
    with pytest.raises(InputError, match=r"q.panda_joint1', row 2500 \(line 2502\).*degrees"):
        load_run(write_csv(tmp_path / "deg.csv", header, rows), known_joints=JOINTS)


def test_a_piece_too_short_is_left_out_and_said_and_a_log_of_only_such_pieces_is_refused(tmp_path):
    header, rows = good_rows(n=9000)
    # 0.4 s between two lost stretches: too short once 0.3 s are trimmed at each end
    lost = [r for r in rows if not (3.0 <= r[0] < 3.2 or 3.6 <= r[0] < 3.8)]
    prepared = load_prepared_runs(_listing(tmp_path, header, lost), JOINTS, root=tmp_path)
    assert [p.name for p in prepared] == ["one#1", "one#3"]
    assert [(round(p.from_s, 2), p.kept) for p in prepared[0].filter.gaps.pieces] == [
        (0.0, True), (3.2, False), (3.8, True)]
    # Every stretch between losses too short: refused, naming the file, the column, the gaps and the fix.
    choppy = [r for r in rows if (r[0] % 0.5) < 0.4]
    with pytest.raises(InputError) as error:
        load_prepared_runs(_listing(tmp_path, header, choppy), JOINTS, root=tmp_path)
    message = str(error.value)
    assert "a.csv: column 'time'" in message and "gap(s) longer than 0.02 s" in message
    assert "gaps.max_step_s" in message and "Fix:" in message


@given(cuts=st.lists(st.integers(1, 2998), max_size=6, unique=True), threshold=st.sampled_from([0.002, 0.02]))
@settings(max_examples=40, deadline=None)
def test_split_at_gaps_keeps_every_row_once_in_order(cuts, threshold):
    """Whatever the losses, the pieces hold every logged row once, in order, and no step inside a piece is a gap."""
    from sim2real.measurements.cleaning import split_at_gaps

    t = np.arange(3000) * 0.001
    for cut in sorted(cuts):
        t[cut:] += 0.05  # a lost stretch before row `cut`
    q = np.column_stack([t, -t])
    run = Run("r", Path("r.csv"), JOINTS, t, q, None, q.copy(), None, None, RunMeta("panda", "real", "torque"))
    pieces = split_at_gaps(run, threshold)
    assert np.array_equal(np.concatenate([p.time for p in pieces]), t)
    assert np.array_equal(np.concatenate([p.tau for p in pieces]), q)
    assert all(np.all(np.diff(p.time) <= threshold) for p in pieces)
    assert len(pieces) == 1 + len(cuts) and (len(pieces) > 1 or pieces[0] is run)


def test_lone_torque_spikes_are_replaced_and_counted_steps_and_turns_are_not():
    """A bus error puts one torque sample far off: the median of it and its neighbours replaces it. A real torque's
    steps (friction reversing at 30 Hz) and smooth turns are never taken for one, with noise or without (a torque
    logged in quanta has no white noise to measure)."""
    from sim2real.measurements.cleaning import lone_spikes, without_spikes

    rng = np.random.default_rng(3)
    t = np.arange(20000) * 0.001
    _, _, qdd = motion(t)
    clean = 2.0 * qdd + 0.8 * np.tanh(np.column_stack([np.cos(1.3 * t), np.sin(0.9 * t)]) / 0.01)
    noisy = clean + 0.03 * rng.standard_normal(clean.shape)
    assert not lone_spikes(noisy).any() and not lone_spikes(clean).any()
    spiked = noisy.copy()
    rows = rng.choice(np.arange(1, 19999), size=12, replace=False)
    spiked[rows, np.arange(12) % 2] += np.array([1.0, -1.0] * 6) * np.geomspace(0.75, 30.0, 12)  # 25 to 1000 sigma
    flags = lone_spikes(spiked)
    assert sorted(zip(*np.nonzero(flags))) == sorted(zip(rows, np.arange(12) % 2))
    assert np.max(np.abs(without_spikes(spiked, flags) - noisy)) < 0.2
    # 30 Hz: friction reversals are steps of 50 noise levels between two samples; logged in 0.01 N m quanta
    slow = clean[::33]
    assert not lone_spikes(slow + 0.03 * rng.standard_normal(slow.shape)).any()
    quantized = np.round(slow / 0.01) * 0.01
    quantized[100, 1] += 1.0
    assert list(zip(*np.nonzero(lone_spikes(quantized)))) == [(100, 1)]


@given(steps=st.lists(st.floats(0.0, 10.0), min_size=3, max_size=60), offset=st.floats(-100.0, 100.0),
       gain=st.floats(0.01, 100.0))
@settings(max_examples=60, deadline=None)
def test_a_monotone_torque_has_no_spike_whatever_its_offset_and_units(steps, offset, gain):
    from sim2real.measurements.cleaning import lone_spikes

    torque = offset + gain * np.cumsum(steps)[:, None] * np.array([1.0, -1.0])
    assert not lone_spikes(torque).any()


def test_a_prepared_run_counts_the_spikes_it_replaced_in_positions_and_torques(tmp_path):
    header, rows = good_rows()
    rows[1200][3] += 5.0  # tau.panda_joint1, 1.2 s
    rows[2100][4] -= 5.0  # tau.panda_joint2
    rows[2101][4] -= 5.0  # two samples in a row: not a lone spike, left (and judged) as logged
    # q.panda_joint2: an encoder's glitch, which filtered and differentiated twice would kick the acceleration
    rows[1500][2] += 0.2
    prepared = prepare_run(load_run(write_csv(tmp_path / "log.csv", header, rows)))
    assert prepared.filter.spikes == SpikeRecord(20.0, {"q": {"panda_joint2": 1}, "tau": {"panda_joint1": 1}})
    assert prepared.filter.as_document()["spikes"] == {"scales": 20.0, "replaced": {"q": {"panda_joint2": 1},
                                                                                    "tau": {"panda_joint1": 1}}}
    _, _, qdd = motion(prepared.time)
    assert np.max(np.abs(prepared.qdd - qdd)) < 0.03  # as the log without the glitch
    assert "spikes" not in prepare_run(load_run(write_csv(tmp_path / "clean.csv", *good_rows()))).filter.as_document()


def _two_logged_runs(tmp_path):
    """A dev Panda (URDF, MJCF), a CSV fit run and a Parquet holdout run, their list, model.yaml, robot.yaml."""
    from gap_fixtures import build_dev_panda
    from sysid_synthetic import PANDA_JOINTS, make_run

    urdf, mjcf = build_dev_panda(tmp_path / "panda")
    for file, seed in (("a.csv", 1), ("b.parquet", 2)):
        run = make_run(file, {}, seed, duration=4.0)
        write_run(tmp_path / file, run.time, PANDA_JOINTS, {"q": run.q, "tau": run.tau}, META)
    listing = tmp_path / "measurements.yaml"
    listing.write_text(yaml.safe_dump({"runs": [{"name": "a", "path": "a.csv", "role": "fit"},
                                                {"name": "b", "path": "b.parquet", "role": "holdout"}]}))
    (tmp_path / "model.yaml").write_text("effects: []\nfit: {bootstrap_replicates: 5, fit_rate_hz: 100}\n")
    (tmp_path / "robot.yaml").write_text(yaml.safe_dump({"armature": {"panda_joint*": 0.1}, "flange": "panda_link8"}))
    return urdf, mjcf, listing


def _counting_reads(monkeypatch):
    from sim2real.measurements.runs import measurement_list, reading

    reads: Counter[str] = Counter()

    def counting(reader):
        def read(path, *args, **kwargs):
            reads[Path(path).name] += 1
            return reader(path, *args, **kwargs)
        return read

    monkeypatch.setattr(reading, "_read_table", counting(reading._read_table))
    for module in (reading, measurement_list):
        monkeypatch.setattr(module, "read_validated_yaml", counting(module.read_validated_yaml))
    return reads


def test_each_rule_reads_each_run_file_once(tmp_path, monkeypatch):
    """sysid and the gap report, given the list, read every run's table and metadata, and the list, exactly once."""
    from sim2real.report.gap import GapInputs, compute_gap
    from sim2real.identification.sysid import SysidFiles, run_sysid

    urdf, mjcf, listing = _two_logged_runs(tmp_path)
    reads = _counting_reads(monkeypatch)
    once = {"measurements.yaml": 1, "a.csv": 1, "a.yaml": 1, "b.parquet": 1, "b.yaml": 1}
    out = tmp_path / "out"
    run_sysid("panda", SysidFiles(urdf, tmp_path / "robot.yaml", tmp_path / "model.yaml", listing,
                                  out / "ladder.json", out / "params.yaml", out / "calibration.yaml", root=tmp_path))
    assert reads == once
    reads.clear()
    compute_gap(GapInputs("panda", urdf, mjcf, listing, root=tmp_path))
    assert reads == once


def test_prepared_runs_are_read_back_exactly_and_the_rules_read_no_run_file(tmp_path, monkeypatch):
    """The prepare_runs rule's file: the same bytes from the same runs, read back to the same numbers, so that
    sysid and the gap report give what they give from the list, without reading or filtering a run again."""
    from sim2real.report.gap import GapInputs, compute_gap
    from sim2real.measurements import prepare_for_model, read_prepared_runs, write_prepared_runs
    from sim2real.identification.sysid import SysidFiles, run_sysid

    urdf, mjcf, listing = _two_logged_runs(tmp_path)
    prepared = prepare_for_model(listing, urdf, root=tmp_path)
    write_prepared_runs(tmp_path / "runs.npz", prepared)
    write_prepared_runs(tmp_path / "again.npz", prepared)
    assert (tmp_path / "runs.npz").read_bytes() == (tmp_path / "again.npz").read_bytes()
    back = read_prepared_runs(tmp_path / "runs.npz")
    assert back.entries == prepared.entries and back.settings == prepared.settings
    for run, read in zip(prepared, back, strict=True):
        for item in dataclasses.fields(run):
            a, b = getattr(run, item.name), getattr(read, item.name)
            assert (a is None and b is None) or (np.array_equal(a, b) if isinstance(a, np.ndarray) else a == b), item.name

    def sysid(source, out):
        run_sysid("panda", SysidFiles(urdf, tmp_path / "robot.yaml", tmp_path / "model.yaml", source,
                                      out / "ladder.json", out / "params.yaml", out / "calibration.yaml", root=tmp_path))
        return (out / "ladder.json").read_bytes()

    from_list = sysid(listing, tmp_path / "list")
    gap_from_list, _ = compute_gap(GapInputs("panda", urdf, mjcf, listing, root=tmp_path))
    reads = _counting_reads(monkeypatch)
    assert sysid(tmp_path / "runs.npz", tmp_path / "prepared") == from_list
    assert compute_gap(GapInputs("panda", urdf, mjcf, tmp_path / "runs.npz", root=tmp_path))[0] == gap_from_list
    assert set(reads) <= {"model.yaml", "robot.yaml"}  # no run, no list
    (tmp_path / "broken.npz").write_bytes(b"half a file")
    with pytest.raises(InputError, match=r"broken\.npz.*not a file of prepared runs.*forcerun prepare_runs"):
        read_prepared_runs(tmp_path / "broken.npz")


def test_mcap_bag_converts_to_run(tmp_path):
    from mcap_ros2.writer import Writer

    joint_state = (
        "std_msgs/Header header\nstring[] name\nfloat64[] position\nfloat64[] velocity\nfloat64[] effort\n"
        "================================================================================\n"
        "MSG: std_msgs/Header\nbuiltin_interfaces/Time stamp\nstring frame_id\n"
        "================================================================================\n"
        "MSG: builtin_interfaces/Time\nint32 sec\nuint32 nanosec\n"
    )
    array = (
        "MultiArrayLayout layout\nfloat64[] data\n"
        "================================================================================\n"
        "MSG: std_msgs/MultiArrayLayout\nMultiArrayDimension[] dim\nuint32 data_offset\n"
        "================================================================================\n"
        "MSG: std_msgs/MultiArrayDimension\nstring label\nuint32 size\nuint32 stride\n"
    )
    bag = tmp_path / "arm.mcap"
    t = np.arange(1500) * 0.002
    q, qd, qdd = motion(t)
    with bag.open("wb") as stream:
        writer = Writer(stream)
        js = writer.register_msgdef("sensor_msgs/msg/JointState", joint_state)
        cmd = writer.register_msgdef("std_msgs/msg/Float64MultiArray", array)
        for k, stamp in enumerate(t):
            ns = int(round((100.0 + stamp) * 1e9))
            writer.write_message("/effort_controller/commands", cmd,
                                 {"layout": {"dim": [], "data_offset": 0}, "data": list(2.0 * qdd[k])}, log_time=ns - 1)
            writer.write_message("/joint_states", js, {
                "header": {"stamp": {"sec": ns // 10**9, "nanosec": ns % 10**9}, "frame_id": ""},
                "name": JOINTS, "position": list(q[k]), "velocity": list(qd[k]), "effort": list(2.0 * qdd[k] + 0.1),
            }, log_time=ns)
        writer.finish()
    out = mcap_to_run(bag, tmp_path / "arm.parquet", robot="panda", command_topic="/effort_controller/commands",
                      torque_sensor="link")
    run = load_run(out, known_joints=JOINTS)
    assert run.meta.source == "real" and run.meta.control_mode == "torque"
    assert run.meta.torque_sensor == "link"  # a Panda's effort is tau_J, measured after the gearbox
    assert run.time[0] == 0.0 and run.time.size == t.size
    assert np.allclose(run.q, q) and np.allclose(run.tau_cmd, 2.0 * qdd) and np.allclose(run.tau, 2.0 * qdd + 0.1)


def test_header_only_table_is_too_short(tmp_path):
    """Found by tests/test_fuzz_inputs.py (issue 21): an IndexError instead of the message."""
    header, _ = good_rows()
    path = write_csv(tmp_path / "empty.csv", header, [])
    with pytest.raises(InputError, match=r"empty.csv: column 'time': run too short to judge \(0 samples"):
        load_run(path)


@pytest.mark.parametrize("edit", ["absurd_stamp", "rate_in_khz"])
def test_absurd_stamp_or_rate_is_refused_before_the_grid(tmp_path, edit):
    """Found by tests/test_fuzz_inputs.py (issue 21): one stamp of 1e300 s made prepare_run allocate a
    grid of 1e303 points (the process was killed for memory)."""
    header, rows = good_rows()
    meta = dict(META)
    if edit == "absurd_stamp":
        rows[-1][0] = 1e300
    else:
        meta["sample_rate_hz"] = 1e6  # the log is at 1 kHz
    path = write_csv(tmp_path / "log.csv", header, rows, meta)
    with pytest.raises(InputError) as error:
        prepare_run(load_run(path))
    message = str(error.value)
    assert "log.csv: column 'time'" in message and "grid points" in message and "Fix:" in message
    if edit == "absurd_stamp":
        assert "row 2999" in message and "largest gap 1e+300 s" in message


def test_the_torque_sensor_is_one_typed_value_checked_once():
    """Where tau is measured: one default, one check for every caller (the prepared runs and the fit's stacked
    runs alike); runs that mix sensor positions are refused, naming them."""
    from sim2real.identification.fitting import RunSamples, stack_runs
    from sim2real.measurements import DEFAULT_TORQUE_SENSOR, SensorPlacement, measured_after_drive, torque_sensor_of

    assert DEFAULT_TORQUE_SENSOR == "motor" and tuple(SensorPlacement) == ("motor", "link")
    t = np.arange(200) * 0.01
    zeros = np.zeros((200, 1))

    def run(name, sensor=DEFAULT_TORQUE_SENSOR, source="tau"):
        return RunSamples(name, t, zeros, zeros, zeros, zeros, source, False, np.ones(1), sensor)

    assert torque_sensor_of([run("a", "link"), run("b", "link")]) == "link"
    assert torque_sensor_of([run("c", "link", source="tau_cmd")]) == DEFAULT_TORQUE_SENSOR
    with pytest.raises(InputError, match=r"mix torque sensor positions: a \(link\), b \(motor\)"):
        torque_sensor_of([run("a", "link"), run("b", "motor")])
    with pytest.raises(InputError, match="mix torque sensor positions"):
        stack_runs([run("a", "link"), run("b", "motor")], ["j"])
    assert measured_after_drive("tau", "link") and not measured_after_drive("tau_cmd", "link")
