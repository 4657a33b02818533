# The base layer: option types and small shared types every other package may import.
