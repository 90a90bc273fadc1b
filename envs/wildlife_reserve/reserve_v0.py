from wildlife_reserve.reserve.reserve import env, parallel_env, raw_env

__all__ = ["env", "parallel_env", "raw_env"]
