def task_file_to_task_class(name: str) -> str:
    return name  # the stand-in environment finds a task's episodes by its file name
