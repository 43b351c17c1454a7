"""One reader per mesh format (OBJ+MTL, PLY, STL, GLB) and what they share (:mod:`.common`)."""
