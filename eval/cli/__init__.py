"""The console scripts of evaluation, export and prediction: thin shells over one call each."""
