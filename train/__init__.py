"""Training the sensorimotor predictive network by streaming lake datasets (smtrain)."""
