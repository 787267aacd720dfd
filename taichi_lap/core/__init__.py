"""The bottom layer: errors, typed parameters, field groups, compressed-row lists,
geometry records and the instrument vocabulary. It imports nothing else of the package;
every other layer may import it."""
