"""The service for one head: `headctl.service.daemon.Daemon` and its parts, one module a job."""
