"""From a user's record to the RunConfig `mop train` trains.

- given: the records as given (read once at the edge), named in the config and split;
- layers: the config's layers (a preset or experiment, the data, the recipes, the overrides): a run from
  scratch in one downward sequence (scratch_config);
- records: the records recipe before training (orders, the cubic NARX choice, model and budget);
- plan: what the records recipe decides for one record (RecordsPlan);
- selection: the records recipe after training (the network's gain or the better fitted linear model, on
  held-out data);
- finetune: the fine-tune recipe of `--init SOURCE`: its config (fine_tune_config);
- source: the fine-tune's source (its architecture check, its weights at step 0);
- shrink: the correction's gain chosen after a fine-tune (train.shrink_correction);
- training: mop.train's loop with those steps around it;
- fit: the one sequence from a record to a run, config, training and held-out choice (fit_record from
  scratch, fine_tune_record with --init: what `mop train` and mop.estimators.Learned call);
- budget: the steps a training budget in minutes buys on a record.

It sits above mop.train (which trains a resolved config) and mop.experiments (whose experiments `mop train
EXPERIMENT` reads), below mop.commands and mop.estimators.
"""

from mop.recipe.layers import training_config

__all__ = ["training_config"]
