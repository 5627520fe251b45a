"""The service for one head: `Daemon` (see `headctl.service.daemon`) and its parts, one module a job."""
from headctl.service.daemon import Daemon

__all__ = ["Daemon"]
