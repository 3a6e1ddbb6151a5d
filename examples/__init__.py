"""Example tasks that live outside the package, as a user's own tasks do (see the README's "Write your own task")."""
