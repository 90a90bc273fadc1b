"""Files and trust: what the package writes, atomically (``atomic_files``, ``pickling``), and what it accepts, checked:
configs and YAML (``safe_config``), pickles and model zips read as data (``safe_pickle``, ``safe_zip``), call
signatures (``signatures``), hyperparameters and flags (``validation``, ``arguments``) and the optional extras
(``extras``). It imports nothing else of the package: every other folder builds on it."""
