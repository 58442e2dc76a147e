"""Benchmarks of the client side: the learner (``ddqn``) and the K-stream trainer (``distributed``)."""
