"""The hostile cases of issue 52 (tests/fuzz_zoo.py, ``hostile_cases``): command lines, -conf files and tampered run
folders that try to run code, each trying to create a marker file. None may create it, print a traceback (every refusal
is one ``error:`` line), leave a file behind or be accepted. The whole set runs in a few seconds."""

import collections

import torch as th
from fuzz_zoo import hostile_cases, run_hostile_case, train_template_run


def test_no_hostile_case_runs_code_prints_a_traceback_or_leaves_a_file(tmp_path):
    th.set_num_threads(1)
    cases = hostile_cases()
    assert len(cases) >= 200
    template = train_template_run(tmp_path / "template")
    counts, failures = collections.Counter(), []
    for i, case in enumerate(cases):
        outcome = run_hostile_case(case, tmp_path / str(i), template)
        for name in ("marker", "traceback", "leftover", "accepted"):
            if outcome[name]:
                counts[name] += 1
                failures.append(f"{name}: {case.name}: {outcome['text']}")
    print(f"{len(cases)} hostile cases: {dict(counts)}")
    assert not failures, "\n".join(failures)
