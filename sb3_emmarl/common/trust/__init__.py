"""Files and trust: what the package writes (atomically: :mod:`.atomic_files`, :mod:`.pickling`) and what it accepts,
checked (configs and YAML: :mod:`.safe_config`; pickles and model zips read as data: :mod:`.safe_pickle`,
:mod:`.safe_zip`; call signatures: :mod:`.signatures`; hyperparameters and flags: :mod:`.validation`,
:mod:`.arguments`; optional extras: :mod:`.extras`). It imports nothing else of the package: every other folder
builds on it."""
