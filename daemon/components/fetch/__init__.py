# The fetch behaviour: drive to an object, grasp it, carry it to a drop point, put it down.
