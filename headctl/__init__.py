"""headctl: the stereo-head driver service (config, threads, realtime loop, persistence, CLI)."""
__version__ = "0.1.0"
