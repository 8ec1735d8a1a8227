"""Shards: the embarrassingly parallel jobs (SMM data, the IK-NN data set, benchmark sweeps) on one
machine or a Ray cluster, checkpointed per shard so a rerun resumes (engine.py, store.py, docs/cluster.md)."""
from armbridge.shards.engine import Job, Runner, Shard

__all__ = ["Job", "Runner", "Shard"]
