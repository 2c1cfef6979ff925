"""StableMo's side of foot skating (the footskate package never imports stablemo): consistent features from cleaned joints, the StableMoFusion* sample hook, skating metrics."""
