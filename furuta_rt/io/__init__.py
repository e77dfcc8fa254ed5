"""Recordings in and out: CSV (t, theta, theta_dot, phi, u), other rigs' CSVs through a column mapping,
and MCAP logs (layout in furuta_rt.io.log_schema).

    read_recording(path, mapping=None) -> Recording      any format (furuta_rt.io.recordings)
    read_log(path) -> LogData                             a log's columns, metadata, rig (furuta_rt.io.mcap_read)
    LogWriter / write_recording_mcap                      writing the log layout (furuta_rt.io.mcap_log)
    repair_log(path)                                      rewrite a killed run's log with a summary (furuta_rt.io.repair)
"""
