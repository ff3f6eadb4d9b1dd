"""The benchmark: grid files (`grid`), the runner (`runner`), the results store (`results`), reports (`report`)."""
