"""Every fuzzed hyperparameter (YAML and -params) and flag either runs or fails cleanly: exit code 2, an error line
naming the argument, no run folder (the cases and the oracle are in tests/fuzz_zoo.py)."""

import collections

import torch as th
from fuzz_zoo import FAILURES, cases, run_case


def test_zoo_fuzz_has_no_unclean_failure_and_no_silent_acceptance(tmp_path):
    th.set_num_threads(1)
    all_cases = cases()
    assert len(all_cases) >= 100 and sum(c.valid for c in all_cases) >= 20
    counts, failures = collections.Counter(), []
    for i, case in enumerate(all_cases):
        outcome, text = run_case(case, tmp_path / str(i))
        counts[outcome] += 1
        if outcome in FAILURES:
            failures.append(f"{outcome}: {case.name}: {text.strip()[-300:]}")
    print(dict(counts))
    assert not failures, "\n".join(failures)
    assert counts["ran"] == sum(c.valid for c in all_cases)
