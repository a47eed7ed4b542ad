"""Gaze sources: the devices that produce gaze samples for the HMI, real, recorded or simulated.

What lives here, one module per source: the tracker on a serial port (:mod:`.serial`), recorded gaze files and
their replay (:mod:`.replay`), the virtual subject of simulated trials (:mod:`.virtual`); what they share
(:mod:`.base`: iteration, close, real-time pacing, and the protocol of a stream decoder); and the tracker's ASCII
line format (:mod:`.line_format`), the serial source's default decoder. A decoder for another wire format (e.g.
the tracker's binary output) is one more module next to :mod:`.line_format` with a class following
:class:`~wamctl.backends.gaze.base.GazeStreamDecoder`, handed to ``SerialGazeSource(..., decoder=...)``.

The samples, their classification, the image geometry and the :class:`~wamctl.hmi.gaze.GazeSource` protocol
the controller reads from are HMI logic and live in :mod:`wamctl.hmi.gaze`.

May import: hmi (samples), io, errors, and pyserial (lazily, in :mod:`.serial` only). Never analysis,
experiments, report or the CLI.
"""
