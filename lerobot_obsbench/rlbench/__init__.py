"""RLBench (the other half of OBSBench): its demonstration format, task table, language goals and the
evaluation protocol, without importing rlbench or pyrep until a simulator is asked for."""
