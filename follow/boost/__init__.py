"""The online boosting classifier that learns the target's appearance."""
