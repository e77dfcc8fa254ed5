"""How well a model explains the recording: where the mismatch lives (locate), the sensors' noise floor (noise),
multi-step prediction and closed-loop re-simulation (verify), the verdict per equation (verdict)."""
