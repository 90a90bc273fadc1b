from wildlife_reserve.zone_patrol.zone_patrol import env, parallel_env, raw_env

__all__ = ["env", "parallel_env", "raw_env"]
