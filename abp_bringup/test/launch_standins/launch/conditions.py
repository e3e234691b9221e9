"""Stand-in for `launch.conditions` (Jazzy): the predicate expression, recorded."""


class IfCondition:
    negate = False

    def __init__(self, predicate_expression):
        self.predicate_expression = predicate_expression


class UnlessCondition(IfCondition):
    negate = True
