"""Files a pipeline run keeps at the top of its folder, beside the stage folders.

Named here, apart from the runner that writes them, because the model cards read them back and
the runner releases models with those cards: both import this module, not each other.
"""

RECIPE_FILE = "pipeline.yaml"  # the resolved profile, overrides applied: the recipe a card names and hashes
COMMAND_FILE = "command.txt"  # the command line of the run's last invocation, for the model cards
