"""The bus on record: MCAP recordings of a run (`ares record`, `ares run --record`), their replay
(`ares replay FILE.mcap`) and the live Foxglove bridge (`ares run --foxglove`).

- recorder.py: every key of the vehicle to an MCAP file, from a writer thread;
- foxglove_views.py: what Foxglove draws (poses, clouds, the grid, the plan) made from ARES messages;
- mcap_replay.py: a recording read back (even one cut short), played into a bus, or its messages fed
  to the replay of one node (ares.core.bus_replay rebuilds the node's steps from them);
- foxglove_live.py: the live bus served to Foxglove over its WebSocket protocol.
"""
