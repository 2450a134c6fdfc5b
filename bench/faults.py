"""The long fault runs of issue 42, with the daemon as a process on loopback (the suite runs short ones):

    python -m bench.faults [--silence-s 10] [--flood-s 10] [--flood-rate 1000] [--json out/faults.json]

- autopilot silent for --silence-s (heartbeats stop, then resume) while the daemon tracks with gimbal
  rates and velocity guidance: when the loss is reported, that no command goes out while silent, how
  soon commands resume (tests/test_fault_autopilot.py's run_silence);
- a ground station sending --flood-rate COMMAND_LONG a second for --flood-s: ACKs by result against
  commands sent, the frame rate against the same window without the flood, the daemon's CPU
  (tests/test_fault_flood.py's run_flood).
Figures are printed and written as JSON; docs/service.md ("Faults") quotes them.
"""
from __future__ import annotations

import argparse
import json
import tempfile
from pathlib import Path

from tests.test_fault_autopilot import TIMEOUT_S, run_silence
from tests.test_fault_flood import run_flood, summary


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench.faults", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--silence-s", type=float, default=10.0, help="autopilot silence, s (0: skip)")
    parser.add_argument("--flood-s", type=float, default=10.0, help="flood duration, s (0: skip)")
    parser.add_argument("--flood-rate", type=float, default=1000.0, help="COMMAND_LONG per second")
    parser.add_argument("--json", type=Path, help="write the figures here")
    args = parser.parse_args(argv)
    figures: dict[str, object] = {}
    with tempfile.TemporaryDirectory(prefix="jsar-faults-") as tmp:
        if args.silence_s > 0:
            workdir = Path(tmp) / "silence"
            workdir.mkdir()
            silence = run_silence(workdir, args.silence_s)
            figures["autopilot_silence"] = silence
            print(f"autopilot silent {silence['silence_s']:.0f} s (heartbeat timeout {TIMEOUT_S:.0f} s): reported "
                  f"{silence['detect_after_timeout_s']:.3f} s after the timeout; last command "
                  f"{silence['last_command_after_silence_s']:.3f} s into the silence, none after; "
                  f"{silence['held']} held, {silence['frames_tracked_while_silent']} frames tracked meanwhile; "
                  f"resumed: gimbal {silence['gimbal_resume_s']:.3f} s, setpoints {silence['setpoint_resume_s']:.3f} s",
                  flush=True)
        if args.flood_s > 0:
            workdir = Path(tmp) / "flood"
            workdir.mkdir()
            flood = run_flood(workdir, args.flood_rate, args.flood_s)
            flood["acks"] = {f"{c}/{r}": n for (c, r), n in flood["acks"].items()}
            flood["refusals"] = {f"{c}/{r}": v for (c, r), v in flood["refusals"].items()}
            flood["wrong_results"] = {f"{c}/{r}": n for (c, r), n in flood["wrong_results"].items()}
            figures["command_flood"] = flood
            print(summary(flood), flush=True)
            print(f"  every command answered: {flood['all_answered']} ({flood['answered']}/{flood['sent']}); "
                  f"refusals by kind with their reasons: {flood['refusals']}", flush=True)
    if args.json is not None:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(figures, indent=1, default=str), encoding="utf-8")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
