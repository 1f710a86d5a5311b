"""Flight logs: the CSV format, derived motion, resampling and the converters from other logs."""
