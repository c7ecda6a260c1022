"""pymagcal against the command line it binds: the same log and options give the same bytes.

Run from a virtual environment with the wheel installed (`.ci/run` does):

    pytest crates/magcal-py/tests

The public logs are read in place from `../shared/data` beside the repository, and the command
line is `target/release/magcal` (or `MAGCAL_BIN`); without them a test says it skipped, and under
`CI=true` it fails.
"""

import csv
import json
import os
import pathlib
import subprocess

import numpy as np
import pytest

import pymagcal

ROOT = pathlib.Path(__file__).resolve().parents[3]
DATA = ROOT.parent / "shared" / "data"
CK = DATA / "ck-explorer" / "acc_mag_log.csv"
BROAD_10 = DATA / "broad" / "10_undisturbed_slow_translation_A.csv"
ARDUPILOT = DATA / "ardupilot" / "pymavlink_test.BIN"
MAGCAL = pathlib.Path(os.environ.get("MAGCAL_BIN", ROOT / "target" / "release" / "magcal"))


def need(*paths):
    """Skips (fails under CI=true) where a file the test reads is missing."""
    for p in paths:
        if not p.exists():
            if os.environ.get("CI") == "true":
                pytest.fail(f"{p} is missing")
            pytest.skip(f"{p} is missing")


def magcal(*args):
    """The command line's exit code, standard output and standard error."""
    need(MAGCAL)
    done = subprocess.run([str(MAGCAL), *map(str, args)], capture_output=True, text=True)
    return done.returncode, done.stdout, done.stderr


def test_the_ck_explorer_log_calibrates_to_the_command_lines_json_byte_for_byte():
    need(CK)
    log = pymagcal.read_log(CK, columns="mx,my,mz")
    assert len(log) == 12000 and log.readings.shape == (12000, 3)
    assert log.columns == ["mx", "my", "mz"] and log.format == "csv" and log.times is None
    cal = pymagcal.calibrate(log)
    code, out, _ = magcal("calibrate", CK, "--columns", "mx,my,mz", "--json")
    assert code == 0
    assert cal.json == out
    # The typed fields are the JSON's numbers, exactly.
    j = json.loads(out)
    assert cal.usable is True and cal.fit == "full" and cal.reasons == []
    assert cal.bias.tolist() == j["bias"]
    assert cal.scale.tolist() == j["scale"]
    assert cal.psi_deg.tolist() == j["psi_deg"]
    assert cal.k.tolist() == j["k"]
    assert cal.soft_iron_inverse.tolist() == j["soft_iron_inverse"]
    assert cal.std_error == j["std_error"]
    assert cal.magnitude == j["magnitude"] and cal.noise == j["noise"]
    # The log's readings are its columns 4 to 6, as numpy reads them.
    expected = np.loadtxt(CK, delimiter=",", skiprows=1, usecols=(3, 4, 5))
    assert np.array_equal(log.readings, expected)
    assert log.lines.tolist() == list(range(2, 12002))


def test_options_are_the_flags_of_the_same_name():
    need(CK)
    cal = pymagcal.calibrate(pymagcal.read_log(CK, columns="mx,my,mz"), fit="auto", reject=3.5, trials=40, seed=7)
    code, out, _ = magcal(
        "calibrate", CK, "--columns", "mx,my,mz", "--fit", "auto", "--reject", "3.5", "--trials", "40", "--seed", "7", "--json"
    )
    assert code == 0 and cal.json == out
    assert json.loads(out)["rejected"] > 0


def test_apply_gives_the_command_lines_calibrated_readings(tmp_path):
    need(CK)
    log = pymagcal.read_log(CK, columns="mx,my,mz")
    cal = pymagcal.calibrate(log)
    saved = tmp_path / "calibration.json"
    saved.write_text(cal.json)
    code, out, _ = magcal("apply", saved, CK, "--columns", "mx,my,mz")
    assert code == 0
    rows = np.array([[float(x) for x in line.split(",")[1:4]] for line in out.splitlines()[1:]])
    assert np.array_equal(cal.apply(log.readings), rows)
    # read back, the file is the same calibration.
    again = pymagcal.read_calibration(saved)
    assert np.array_equal(again.apply(log.readings), rows) and again.json == cal.json


def test_export_is_the_command_lines_but_for_the_name_of_the_calibration(tmp_path):
    need(CK)
    cal = pymagcal.calibrate(pymagcal.read_log(CK, columns="mx,my,mz"), units="uT")
    saved = tmp_path / "calibration.json"
    saved.write_text(cal.json)
    for target in ["ardupilot", "px4", "motioncal", "magneto", "c"]:
        code, out, _ = magcal("export", saved, "--to", target)
        assert code == 0, target
        text = pymagcal.export(cal, target)
        # The header names the calibration: its file for the command line, its log here.
        assert str(saved) in out
        assert text == out.replace(str(saved), f"the calibration of {CK}"), target


def test_an_array_of_a_known_sensor_gives_its_bias_and_matrix():
    # Readings of a sensor with a full K and a bias, noise-free, over every direction of a 48 uT
    # field (a spiral on the sphere).
    n = 600
    z = 1 - (2 * np.arange(n) + 1) / n
    a = np.arange(n) * 2.399963229728653
    field = 48.0 * np.column_stack([np.sqrt(1 - z * z) * np.cos(a), np.sqrt(1 - z * z) * np.sin(a), z])
    K = np.array([[1.05, 0.0, 0.0], [0.02, 0.97, 0.0], [-0.01, 0.015, 1.02]])
    bias = np.array([3.0, -1.5, 0.5])
    raw = field @ K.T + bias
    cal = pymagcal.calibrate(raw, magnitude=48.0)
    assert cal.usable and cal.fit == "full"
    # The fit stops at its gradient tolerance: the residual of noise-free readings is rounding.
    assert np.max(np.abs(cal.bias - bias)) < 1e-9 * 48
    # A field of one magnitude determines K up to a rotation: K K^T, whatever form K is given in.
    assert np.max(np.abs(cal.k @ cal.k.T - K @ K.T)) < 1e-9
    assert np.max(np.abs(np.linalg.norm(cal.apply(raw), axis=1) - 48.0)) < 1e-9 * 48
    # The same readings through a CSV file and the command line: the same numbers.
    j = json.loads(cal.json)
    assert j["log"] == "<array>" and j["samples"] == n


def test_the_heading_budget_is_a_keyword_and_its_verdict_is_read_back():
    # 600 readings of a known sensor with noise 0.05 uT in a 48 uT field: the heading it leaves
    # at level is a few hundredths of a degree; a budget below that refuses it, naming both
    # figures, as the command line does with --heading-budget.
    rng = np.random.default_rng(7)
    n = 600
    z = 1 - (2 * np.arange(n) + 1) / n
    a = np.arange(n) * 2.399963229728653
    field = 48.0 * np.column_stack([np.sqrt(1 - z * z) * np.cos(a), np.sqrt(1 - z * z) * np.sin(a), z])
    raw = field * np.array([1.05, 0.97, 1.02]) + np.array([3.0, -1.5, 0.5]) + rng.normal(0, 0.05, (n, 3))
    cal = pymagcal.calibrate(raw)
    assert cal.usable and cal.heading_budget_deg == 2.0
    assert 0 < cal.heading_deg < 0.2, cal.heading_words
    assert "inclination from an assumed 60 deg" in cal.heading_words
    strict = pymagcal.calibrate(raw, heading_budget=cal.heading_deg / 2)
    assert not strict.usable and strict.heading_budget_deg == cal.heading_deg / 2
    assert strict.reasons[0].startswith("heading budget not met"), strict.reasons
    assert json.loads(strict.json)["heading_budget"]["met"] is False


def test_errors_are_the_command_lines_one_line_messages():
    need(CK)
    log = pymagcal.read_log(CK, columns="mx,my,mz")
    with pytest.raises(pymagcal.InputError) as e:
        pymagcal.calibrate(log, fit="bogus")
    _, _, err = magcal("calibrate", CK, "--columns", "mx,my,mz", "--fit", "bogus")
    # The command line keeps clap's layout (the message, its details indented, the usage line and
    # the pointer to --help); Python's message is that message on one line.
    message = [l.strip() for l in err.splitlines() if l.strip() and not l.startswith(("Usage:", "For more information"))]
    assert " ".join(message) == "magcal: error: " + str(e.value)
    with pytest.raises(pymagcal.InputError) as e:
        pymagcal.calibrate(log, trials=5)
    assert "--trials" in str(e.value)
    with pytest.raises(pymagcal.InputError) as e:
        pymagcal.read_log(CK, columns="mx,my,nope")
    code, _, err = magcal("calibrate", CK, "--columns", "mx,my,nope")
    assert code == 2 and err.strip() == "magcal: error: " + str(e.value)
    with pytest.raises(pymagcal.InputError, match="an array of shape"):
        pymagcal.calibrate(np.zeros((10, 2)))
    # A calibration needs units for an autopilot's parameters.
    with pytest.raises(pymagcal.InputError, match="units"):
        pymagcal.export(pymagcal.calibrate(log), "ardupilot")


def test_a_log_that_determines_nothing_is_not_exported_unless_forced():
    need(BROAD_10)
    cal = pymagcal.calibrate(BROAD_10)
    code, out, _ = magcal("calibrate", BROAD_10, "--json")
    assert code == 3 and cal.json == out
    assert cal.usable is False and cal.reasons == json.loads(out)["reasons"]
    with pytest.raises(pymagcal.UnusableError):
        pymagcal.export(cal, "magneto")
    assert pymagcal.export(cal, "magneto", force=True).startswith("# NOT A CALIBRATION TO USE")


def test_a_dataflash_log_is_read_in_its_units_with_its_attitudes():
    need(ARDUPILOT)
    log = pymagcal.read_log(ARDUPILOT)
    code, out, _ = magcal("calibrate", ARDUPILOT, "--json")
    j = json.loads(out)
    assert log.format == "dataflash" and log.units == "mG"
    assert len(log) == j["samples"] and log.sha256 == j["log_sha256"]
    assert log.times is not None and np.all(np.diff(log.times) >= 0)
    att = log.attitudes
    assert att is not None and att.shape == (len(log), 3, 3)
    # Each attitude is a rotation (where the log has one).
    have = ~np.isnan(att[:, 0, 0])
    assert have.any()
    eye = np.einsum("nij,nkj->nik", att[have], att[have])
    assert np.max(np.abs(eye - np.eye(3))) < 1e-12
    # The log's readings lie far inside the field's magnitude at its site: the command line warns
    # about the units, and Python so.
    with pytest.warns(UserWarning, match="are they in the same units") as caught:
        cal = pymagcal.calibrate(log)
    assert caught[0].filename == __file__
    assert cal.json == out and code == (0 if cal.usable else 3)


GLIDER = ROOT / "scenarios" / "glider.toml"
BROAD_02 = DATA / "broad" / "02_undisturbed_slow_rotation_B.csv"
BROAD_FLAGS = dict(
    where=["movement=1"], columns="mx,my,mz", time="t_s", quaternion="qw,qx,qy,qz", attitude_frame="enu"
)
BROAD_ARGS = [
    "--where", "movement=1", "--columns", "mx,my,mz", "--time", "t_s",
    "--quaternion", "qw,qx,qy,qz", "--attitude-frame", "enu",
]


def same_cell(text, value):
    """A cell of the command line's CSV file and the value Python has for it."""
    if text == "":
        return value is None
    if isinstance(value, bool):
        return text == ("true" if value else "false")
    if isinstance(value, int):
        return int(text) == value
    if isinstance(value, float):
        return float(text) == value
    return text == value


def test_a_plan_is_the_command_lines_design_set(tmp_path):
    plan = pymagcal.design(GLIDER)
    out = tmp_path / "set"
    code, stdout, _ = magcal("design", GLIDER, "--out", out)
    assert code == 0
    assert set(plan.tables) == {"designs.csv", "design_metrics.csv", "approximate.csv", "certificate.csv"}
    for name, rows in plan.tables.items():
        with open(out / name, newline="") as f:
            written = list(csv.DictReader(f))
        assert len(written) == len(rows), name
        for w, r in zip(written, rows):
            assert list(w) == list(r), name
            assert all(same_cell(w[k], r[k]) for k in w), (name, w, r)
    # The recommendation is the one printed, and the design's arrays are its rows of designs.csv.
    assert plan.recommendation in stdout
    best = plan.recommended
    assert best.name == "plan300" and best.works and best.m == 300
    assert f"fly {best.name}:" in stdout
    mine = [r for r in plan.tables["designs.csv"] if r["design"] == "plan300"]
    assert best.roll_deg.tolist() == [r["roll_deg"] for r in mine]
    assert best.readings.sum() == 300 and len(best) == len(mine)
    assert np.allclose(np.linalg.norm(best.quaternions, axis=1), 1, atol=4e-16 * 4)
    assert 0.9 < best.certified_efficiency <= 1
    # A level turn does not fix the up axis: the surface circle does not work.
    assert plan["surface12"].works is False


def test_a_plan_from_the_scenarios_text_and_on_one_thread_is_the_same(tmp_path):
    text = GLIDER.read_text()
    a = pymagcal.design(GLIDER, threads=1)
    b = pymagcal.design(toml=text, threads=2)
    assert a.tables == b.tables
    with pytest.raises(pymagcal.InputError) as e:
        pymagcal.design(toml=text.replace("roll_deg = [-10.0, 10.0]", "roll_deg = [10.0, -10.0]"))
    assert "<scenario>" in str(e.value) and "roll_deg" in str(e.value)
    # A different seed gives other optimised designs.
    assert pymagcal.design(GLIDER, seed=1).tables["designs.csv"] != a.tables["designs.csv"]


def test_evaluate_and_next_are_the_command_lines_json(tmp_path):
    need(BROAD_02)
    cal = pymagcal.calibrate(pymagcal.read_log(BROAD_02, **BROAD_FLAGS), units="uT")
    saved = tmp_path / "calibration.json"
    saved.write_text(cal.json)
    code, out, _ = magcal("evaluate", saved, BROAD_02, *BROAD_ARGS, "--json")
    assert code == 0
    assert pymagcal.evaluate(saved, BROAD_02, **BROAD_FLAGS) == json.loads(out)
    # The object gives the same figures under another name.
    by_object = pymagcal.evaluate(cal, BROAD_02, **BROAD_FLAGS)
    assert by_object["calibrated"] == json.loads(out)["calibrated"]
    code, out, _ = magcal("evaluate", "--raw", BROAD_02, *BROAD_ARGS, "--json")
    assert code == 0 and pymagcal.evaluate(None, BROAD_02, **BROAD_FLAGS) == json.loads(out)
    code, out, _ = magcal("next", saved, BROAD_02, *BROAD_ARGS, "--scenario", GLIDER, "--count", "4", "--json")
    assert code == 0
    nxt = pymagcal.next(saved, BROAD_02, scenario=GLIDER, count=4, **BROAD_FLAGS)
    assert nxt == json.loads(out) and sum(a["readings"] for a in nxt["attitudes"]) == 4
    # The command line's outputs are not options here.
    with pytest.raises(pymagcal.InputError, match="report="):
        pymagcal.evaluate(cal, BROAD_02, report=tmp_path / "page.html", **BROAD_FLAGS)


def test_a_plan_near_the_budget_says_how_many_of_its_logs_calibrate_would_take():
    # The vessel's plan1000 leaves 1.66 degrees in truth against a budget of 2: design flies 20
    # of its logs and judges them as calibrate does; plan300 misses the budget in truth, and no
    # log of it is flown.
    plan = pymagcal.design(ROOT / "scenarios" / "usv.toml")
    fly = plan["plan1000"]
    assert fly.works and isinstance(fly.logs_usable, int) and 18 <= fly.logs_usable <= 20
    assert fly.metrics["check_logs"] == 20 and fly.heading_p95_deg > 1.0
    assert plan["plan300"].logs_usable is None and not plan["plan300"].works


def test_evaluate_without_attitudes_raises_the_command_lines_error(tmp_path):
    need(CK)
    cal = pymagcal.calibrate(pymagcal.read_log(CK, columns="mx,my,mz"))
    saved = tmp_path / "calibration.json"
    saved.write_text(cal.json)
    with pytest.raises(pymagcal.InputError) as e:
        pymagcal.evaluate(saved, CK)
    code, _, err = magcal("evaluate", saved, CK)
    assert code == 2 and err.strip() == "magcal: error: " + str(e.value)


def test_a_plan_is_a_sequence_of_designs_with_counts_as_ints_and_copies_handed_out():
    plan = pymagcal.design(GLIDER)
    assert [d.name for d in plan] == ["optimum12", "random12", "plan300", "surface12"]
    assert "plan300" in plan and "nope" not in plan and 3 not in plan
    assert plan[0].name == "optimum12" and plan[-1].name == "surface12"
    with pytest.raises(IndexError):
        plan[4]
    with pytest.raises(KeyError):
        plan["nope"]
    metrics = plan.tables["design_metrics.csv"]
    for row in metrics:
        assert isinstance(row["m"], int) and isinstance(row["check_ok"], int)
        assert isinstance(row["cond_mf"], float) and isinstance(row["check_sigma_nt"], float)
    assert all(isinstance(r["roll_deg"], float) and isinstance(r["visit"], int) for r in plan.tables["designs.csv"])
    # What is handed out is a copy: the plan does not change.
    plan[0].points[0]["roll_deg"] = 99.0
    plan.tables["designs.csv"][0]["roll_deg"] = 99.0
    assert plan[0].points[0]["roll_deg"] == plan[0].roll_deg[0] != 99.0
    with pytest.raises(pymagcal.InputError, match="not both"):
        pymagcal.design(GLIDER, toml=GLIDER.read_text())
    with pytest.raises(pymagcal.InputError, match="--seed"):
        pymagcal.design(GLIDER, seed=-1)


def test_keywords_are_checked_against_the_flags(tmp_path):
    need(BROAD_02)
    cal = pymagcal.calibrate(pymagcal.read_log(BROAD_02, **BROAD_FLAGS), units="uT")
    with pytest.raises(TypeError, match="unexpected keyword argument 'bogus'"):
        pymagcal.evaluate(cal, BROAD_02, bogus=1, **BROAD_FLAGS)
    with pytest.raises(TypeError, match="'help'"):
        pymagcal.next(cal, BROAD_02, help=True)
    # A value flag given True is refused by name, not read as the flag that follows.
    with pytest.raises(pymagcal.InputError, match="start=: takes a value"):
        pymagcal.evaluate(cal, BROAD_02, start=True, **BROAD_FLAGS)
    with pytest.raises(pymagcal.InputError, match="raw=: give None"):
        pymagcal.evaluate(cal, BROAD_02, raw=True, **BROAD_FLAGS)
    # A MIN,MAX flag takes a tuple; a repeated flag a list.
    box = dict(site="63.43,10.40,50", date="2026-06-01", roll=(-10, 10), pitch=(-20, 20))
    a = pymagcal.next(cal, BROAD_02, count=2, **box, **BROAD_FLAGS)
    b = pymagcal.next(cal, BROAD_02, count=2, **{**box, "roll": "-10,10", "pitch": "-20,20"}, **BROAD_FLAGS)
    # Two readings a pass (an attitude chosen twice is one row), each row counting its readings
    # over every pass tried: the most where none reaches the budget.
    passes = a["passes_to_usable"] or 32
    assert a == b and sum(x["readings"] for x in a["attitudes"]) == a["readings_added"] == 2 * passes


def test_a_path_that_begins_with_a_dash_is_a_path(tmp_path, monkeypatch):
    need(CK)
    monkeypatch.chdir(tmp_path)
    pathlib.Path("-log.csv").write_bytes(CK.read_bytes())
    assert len(pymagcal.read_log("-log.csv", columns="mx,my,mz")) == 12000
    cal = pymagcal.calibrate(pymagcal.read_log("-log.csv", columns="mx,my,mz"))
    pathlib.Path("-cal.json").write_text(cal.json)
    assert pymagcal.read_calibration("-cal.json").json == cal.json


def test_the_command_lines_warnings_are_python_warnings(tmp_path):
    need(BROAD_10)
    # BROAD 10's calibration is marked not identifiable: evaluating with it says so, as a warning.
    cal = pymagcal.calibrate(pymagcal.read_log(BROAD_10, **BROAD_FLAGS), units="uT")
    assert cal.fit is not None and not cal.usable
    with pytest.warns(UserWarning, match="marked not identifiable"):
        ev = pymagcal.evaluate(cal, BROAD_10, **BROAD_FLAGS)
    assert ev["calibration"] == f"the calibration of {BROAD_10}"
    # As errors, warnings stop the call.
    import warnings
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with pytest.raises(UserWarning):
            pymagcal.evaluate(cal, BROAD_10, **BROAD_FLAGS)
