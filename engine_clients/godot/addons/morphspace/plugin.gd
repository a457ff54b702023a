# Registers MorphspaceMesh (a MeshInstance) in the editor's "Create New Node" dialog.
tool
extends EditorPlugin


func _enter_tree():
	add_custom_type("MorphspaceMesh", "MeshInstance", preload("res://addons/morphspace/morphspace_mesh.gd"), null)


func _exit_tree():
	remove_custom_type("MorphspaceMesh")
