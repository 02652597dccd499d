"""The rig on Lab Streaming Layer: the model's signals and trial markers for LabRecorder."""
