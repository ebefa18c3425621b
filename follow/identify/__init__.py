"""Which tracked person is the target: appearance cues, the re-id gallery and the
target state machine."""
