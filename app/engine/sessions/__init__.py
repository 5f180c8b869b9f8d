"""Recorded sessions: the session folder on disk and its markers (session), a recording in
progress and the recording lane (recording), replaying a session or a log with its passes and
seeks (replay) and a replay's background index of checkpoints and plots (index)."""
