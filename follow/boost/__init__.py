"""Online boosting and the target identification state machine."""
