"""Double DQN from pixels (Wei et al. 2019), split into modules a reader finds by name.

* :mod:`~agent_client.rl.config`: :class:`Config`, every setting of a run;
* :mod:`~agent_client.rl.network`: the Q-network and its one inference path;
* :mod:`~agent_client.rl.replay`: the replay memory (frames stored once);
* :mod:`~agent_client.rl.learner`: the :class:`Learner` both trainers feed;
* :mod:`~agent_client.rl.checkpoint`: the one checkpoint layout, with its digest and lineage, and
  the model surgery (average, decide, narrow, export) that ``vacc checkpoint`` runs;
* :mod:`~agent_client.rl.evaluation`: greedy evaluation episodes and their score;
* :mod:`~agent_client.rl.scalars`: ``scalars.csv``/TensorBoard and the progress line;
* :mod:`~agent_client.rl.train`: the single-stream loop (serial or parallel schedule);
* :mod:`~agent_client.rl.distributed`: K streams (local processes or Ray actors);
* :mod:`~agent_client.rl.cli`: ``vacc train``, its options generated from :class:`Config`.

Importing this package imports torch; the controllers that do not need it never do.
"""
