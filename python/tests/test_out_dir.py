"""ConfiguredRun.run(out_dir) keeps the command-line tool's rules for its
output directory: a directory of an earlier run (the tool's or Python's) is
refused unless overwrite=True, and one locked by a running run is refused."""
import fcntl
import subprocess

import pytest

import otfp

OVERRIDES = ["particles.n_inf=150", "run.t_end=0.5", "run.max_steps=2"]


def config_path(source_dir):
    return str(source_dir / "examples" / "sphere_dirichlet.toml")


def cli_run(otfp_cli, source_dir, out, *extra):
    cmd = [otfp_cli, "run", config_path(source_dir), "--out", str(out), "--quiet"]
    for o in OVERRIDES:
        cmd += ["--set", o]
    return subprocess.run(cmd + list(extra), capture_output=True, text=True)


def test_a_command_line_run_is_refused_by_python(tmp_path, source_dir, otfp_cli):
    out = tmp_path / "run"
    assert cli_run(otfp_cli, source_dir, out).returncode == 0
    before = (out / "summary.json").read_text()
    run = otfp.load_config(config_path(source_dir), OVERRIDES)
    with pytest.raises(otfp.OutputDirError) as e:
        run.run(out)
    message = str(e.value)
    assert "\n" not in message
    assert str(out) in message and "summary.json" in message and "overwrite=True" in message
    assert (out / "summary.json").read_text() == before  # nothing touched
    assert not (out / ".otfp.lock").exists()


def test_a_python_run_is_refused_by_the_command_line_and_by_python(tmp_path, source_dir, otfp_cli):
    out = tmp_path / "run"
    run = otfp.load_config(config_path(source_dir), OVERRIDES)
    assert run.run(out)["exit_code"] == 0
    assert not (out / ".otfp.lock").exists()  # released at the end
    r = cli_run(otfp_cli, source_dir, out)
    assert r.returncode == 2 and "holds an earlier otfp run" in r.stderr
    with pytest.raises(otfp.OutputDirError, match="holds an earlier otfp run"):
        run.run(out)
    assert issubclass(otfp.OutputDirError, ValueError)


def test_overwrite_replaces_the_earlier_run_files_only(tmp_path, source_dir, otfp_cli):
    out = tmp_path / "run"
    assert cli_run(otfp_cli, source_dir, out, "--set", "run.max_steps=3").returncode == 0
    (out / "notes.txt").write_text("mine")
    run = otfp.load_config(config_path(source_dir), OVERRIDES)
    result = run.run(out, overwrite=True)
    assert result["exit_code"] == 0
    assert result["summary"]["final"]["step"] == 2
    rows = (out / "series.csv").read_text().strip().splitlines()[1:]
    assert [int(r.split(",")[0]) for r in rows] == [0, 1, 2]  # the earlier run's 4 rows are gone
    assert (out / "notes.txt").read_text() == "mine"  # not a file of a run: left alone


def test_a_held_lock_refuses_the_run(tmp_path, source_dir):
    out = tmp_path / "run"
    out.mkdir()
    with open(out / ".otfp.lock", "w") as held:
        fcntl.flock(held, fcntl.LOCK_EX | fcntl.LOCK_NB)  # as a running otfp run holds it
        run = otfp.load_config(config_path(source_dir), OVERRIDES)
        with pytest.raises(otfp.OutputDirError, match="in use by another otfp run"):
            run.run(out)
        assert list(out.iterdir()) == [out / ".otfp.lock"]
    # Released with the file: now the run goes ahead.
    assert run.run(out)["exit_code"] == 0


def test_not_a_directory_is_refused(tmp_path, source_dir):
    f = tmp_path / "file"
    f.write_text("x")
    run = otfp.load_config(config_path(source_dir), OVERRIDES)
    with pytest.raises(otfp.OutputDirError, match="exists and is not a directory"):
        run.run(f)
