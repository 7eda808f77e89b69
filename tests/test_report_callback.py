"""SweepReportCallback inside a real Hydra multirun (a tiny app that fabricates run dirs),
and its promise never to raise."""

from __future__ import annotations

import logging
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest
from omegaconf import OmegaConf

from slamlab.report.callback import SweepReportCallback

TESTS = Path(__file__).resolve().parent


@pytest.mark.slow
def test_callback_writes_report_after_real_multirun(tmp_path: Path) -> None:
    conf = tmp_path / "conf"
    conf.mkdir()
    # The sweep dir holds ${now:...%f}, like slamlab's: the callback must find the same folder.
    (conf / "config.yaml").write_text(textwrap.dedent(f"""
        particles: 5
        seed: 0
        report: true
        hydra:
          run:
            dir: {tmp_path}/outputs/${{now:%H-%M-%S-%f}}
          sweep:
            dir: {tmp_path}/multirun/${{now:%H-%M-%S-%f}}
            subdir: ${{hydra.job.num}}
          callbacks:
            sweep_report:
              _target_: slamlab.report.callback.SweepReportCallback
    """))
    app = tmp_path / "app.py"
    app.write_text(textwrap.dedent(f"""
        import sys
        from pathlib import Path
        import hydra
        from hydra.core.hydra_config import HydraConfig
        sys.path.insert(0, {str(TESTS)!r})
        from report_fixtures import make_run_dir

        @hydra.main(version_base="1.3", config_path={str(conf)!r}, config_name="config")
        def app(cfg):
            hc = HydraConfig.get()
            make_run_dir(Path(hc.runtime.output_dir), overrides=list(hc.overrides.task), n_steps=40,
                         failure="metrics" if cfg.particles == 7 else None, hydra_files=False)

        if __name__ == "__main__":
            app()
    """))
    proc = subprocess.run([sys.executable, str(app), "-m", "particles=5,7", "seed=0,1"], cwd=tmp_path,
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    sweeps = list((tmp_path / "multirun").iterdir())
    assert len(sweeps) == 1
    report = sweeps[0] / "report.html"
    assert report.is_file(), proc.stderr
    page = report.read_text()
    assert page.count('data-run="') == 4
    assert "slamlab -m particles=5,7 seed=0,1" in page
    assert "expected 360 beams" in page  # the failed job is shown with its error
    assert (sweeps[0] / "runs.csv").is_file()


def test_callback_never_raises(tmp_path: Path, caplog) -> None:
    cb = SweepReportCallback()
    empty = tmp_path / "sweep"
    empty.mkdir()
    (empty / "multirun.yaml").write_text("hydra: {}\n")  # a sweep whose jobs never started
    with caplog.at_level(logging.ERROR):
        cb.on_multirun_start(OmegaConf.create({"hydra": {"sweep": {"dir": str(empty)}}}))
        cb.on_multirun_end(OmegaConf.create({"hydra": {"sweep": {"dir": str(empty)}}}))
        cb.on_multirun_end(OmegaConf.create({"hydra": {"sweep": {"dir": str(tmp_path / "gone")}}}))
        cb.on_multirun_end(OmegaConf.create({}))
    assert "no run directories found" in caplog.text
    assert not (empty / "report.html").exists()
    # `report: false` switches the sweep report off with the run reports.
    SweepReportCallback().on_multirun_end(OmegaConf.create({"report": False, "hydra": {"sweep": {"dir": str(empty)}}}))
