"""The diagnosis stages beyond the regression, one job each: conventions of the recording, free decay, latency,
arm starts, command peaks, rest, stick–slip windows, the prediction gate; and the findings object they work on."""
