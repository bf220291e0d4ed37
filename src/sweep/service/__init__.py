"""The sweep service: config rules, jobs and their outcomes, the orchestration with its executors
(local, Ray), the storage of checkpoints, and MLflow tracking."""
