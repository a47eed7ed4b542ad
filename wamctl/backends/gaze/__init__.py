"""Gaze sources: the devices that produce gaze samples for the HMI, real, recorded or simulated.

What lives here: the tracker on a serial port (:mod:`.serial`); the stream formats it may speak, as decoders chosen
by name (:mod:`.formats`: ``asl-serial-out`` in :mod:`.asl`, the ASL tracker's own binary Serial Out;
``ascii-pair`` in :mod:`.ascii_pair`, the thesis' ``x,y`` lines; ``ascii-timestamped`` in :mod:`.line_format`,
``t_ms,x,y`` lines); raw byte captures (:mod:`.capture`) and their replay, and recorded gaze files (:mod:`.replay`);
what a tracker is sending (:mod:`.check`, ``wamctl gaze-check``); a simulated tracker on a pty for tests and
benchmarks (:mod:`.tracker_sim`); the virtual subject of simulated trials (:mod:`.virtual`); and what they share
(:mod:`.base`: iteration, close, real-time pacing, the decoder protocol, decoded records and their counts).

The samples, their classification, the image geometry and the :class:`~wamctl.hmi.gaze.GazeSource` protocol
the controller reads from are HMI logic and live in :mod:`wamctl.hmi.gaze`.

May import: hmi (samples), io, errors, and pyserial (lazily, in :mod:`.serial` only). Never analysis,
experiments, report or the CLI.
"""
