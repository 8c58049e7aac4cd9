"""servo_app: online servo control of industrial robot arms."""
