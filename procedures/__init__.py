"""QA procedures as readable scripts."""
