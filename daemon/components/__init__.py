# The components: one package each, folder = component name = config section.
