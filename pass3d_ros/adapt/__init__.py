"""Adapting stage 2 to a user's own sensor from an unlabelled recording (a user has no labels of it): the recording
split into stretches of time to adapt on and to check on, and the label-free check read before and after."""
