"""Evaluation of trackers on OTB-layout sequences (one-pass and long-term with injected events).

    python -m jsar.eval DATA_ROOT --trackers jsar,strcf,csrt,kcf [--published DIR] [--json F] [--plots D]
    python -m jsar.eval DATA_ROOT --longterm --trackers jsar-re,jsar,csrt
    python -m jsar.eval.compare RESULT.json SEQUENCE A B

dataset (sequences, published files), metrics (pure scores), longterm (event injection and its
metrics), runner (lockstep timed runs), evaluate (procedures), report (tables, plots, JSON),
synthetic (a clip made in code), compare (two trackers frame by frame).
"""
