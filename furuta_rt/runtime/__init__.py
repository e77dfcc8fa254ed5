"""`furuta-rt run`: the fixed-rate control daemon, ros2_control style.

    hardware    HardwareInterface / SerialHardware: handshake, read SAMPLE, write COMMAND
    supervisor  the safety state machine (pure): idle → armed → balancing → tripped
    loop        the manager: read → Controller.update/hold → write, timing accounting
    timing      device clock, histograms, running statistics
    logger      the MCAP writer process (furuta_rt.io.log_schema layout)
    dashboard   the rich Live dashboard process
    signals     the stop signals: operator stop in the loop, interrupted start-up, ignored in children
    rt          gc freeze, SCHED_FIFO, mlockall, CPU affinity
    daemon      process orchestration and the summary; summary: its text and JSON
"""
