"""Stand-in for `launch.substitutions` (Jazzy): what each substitution is made of."""


class LaunchConfiguration:
    def __init__(self, variable_name, *, default=None):
        self.variable_name = variable_name
        self.default = default


class PythonExpression:
    def __init__(self, expression, python_modules=('math',)):
        self.expression = expression
        self.python_modules = python_modules
