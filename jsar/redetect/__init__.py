"""JSAR-Re: failure monitoring, re-detection by the decision filter and re-acquisition on top of JSAR.

- `jsar_re`: `JsarReTracker` (the orchestrator) and the registry factory `make_jsar_re` ("jsar-re");
- `monitor`: the failure monitor's per-frame verdicts (pure, no I/O);
- `search`: the budgeted lattice search while lost, the acceptance bar and the motion gate (pure);
- `memory`: the decision filter, scoring the core's detection sample and lattice windows;
- `params`: `RedetectParams` (monitor / search / accept groups, errors naming the key);
- `edges`, `proposals`: EdgeBoxes object proposals (the service's click-to-box), not used by the tracker.
Cost of a lost frame against a tracking frame: `python -m bench.redetect`.
"""
