"""labctl: characterize 3D cameras for facial biometrics: run campaigns, evaluate, simulate, reconcile."""
