"""The command line's logging: stderr and the config's log file behind the repeat limit, so a
fault repeated thousands of times writes one line and its summaries (the last at exit)."""
from __future__ import annotations

import re
import subprocess
import sys
import textwrap
from pathlib import Path

REPO = Path(__file__).resolve().parents[3]
COUNT = re.compile(r"\(repeated ([\d,]+) times in the last \d+ s\)$")

SCRIPT = textwrap.dedent("""
    import argparse, dataclasses, logging, sys
    from headctl.cli.main import configure_logging
    from headctl.cli.service import _apply_logging
    from headctl.config.head import LoggingConfig, load_config

    configure_logging("INFO")
    config = load_config()
    config = dataclasses.replace(config, logging=LoggingConfig(file=sys.argv[1], repeat_summary_s=60.0))
    _apply_logging(config, argparse.Namespace(log_level="INFO"))
    log = logging.getLogger("headctl.service.fixation_thread")
    for i in range(10000):
        log.info("fixation aborted: %s", f"servo-bus: no servo state within 1.0 s ({i})")
    logging.getLogger("headctl.service.supervision.supervisor").warning("something else")
""")


def _told(lines: list[str]) -> int:
    """Records a log's fault lines stand for: one per full line, the count per summary."""
    total = 0
    for line in lines:
        match = COUNT.search(line)
        total += int(match.group(1).replace(",", "")) if match else 1
    return total


def test_a_repeated_fault_writes_a_line_and_its_summary_to_stderr_and_the_log_file(tmp_path):
    log_file = tmp_path / "headctl.log"
    result = subprocess.run([sys.executable, "-c", SCRIPT, str(log_file)], cwd=REPO, capture_output=True,
                            text=True, timeout=60, env={"PYTHONPATH": str(REPO), "PATH": "/usr/bin:/bin"})
    assert result.returncode == 0, result.stderr
    for where, text in (("stderr", result.stderr), ("file", log_file.read_text())):
        lines = [line for line in text.splitlines() if "fixation aborted" in line]
        assert lines[0].endswith("fixation aborted: servo-bus: no servo state within 1.0 s (0)"), where
        assert len(lines) == 2, (where, lines)  # the first, and the rest summed up at exit
        assert re.search(r"\(9999\) \(repeated 9,999 times in the last \d+ s\)$", lines[1]), (where, lines)
        assert _told(lines) == 10000
        assert "something else" in text, where
