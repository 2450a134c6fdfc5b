"""Evaluation of trackers on OTB-layout sequences (one-pass and long-term with injected events).

    python -m jsar.eval DATA_ROOT --trackers jsar,strcf,csrt,kcf [--published DIR] [--json F] [--plots D]
    python -m jsar.eval DATA_ROOT --longterm --trackers jsar-re,jsar,csrt
    python -m jsar.eval DATA_ROOT --trackers jsar-re,csrt --starts sre --jobs 2   # from 11 initial boxes
    python -m jsar.eval.compare RESULT.json SEQUENCE A B

dataset (sequences, published files), metrics (pure scores), longterm (event injection and its
metrics), sre (perturbed initial boxes and the spread over them), runner (lockstep timed runs, a
process pool), evaluate (procedures), report (tables, plots, JSON),
synthetic (a clip made in code), compare (two trackers frame by frame).
"""
