"""UV layout and high-to-low map baking (displacement and colour) for the eye region."""
