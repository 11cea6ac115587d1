// The mesh scene of scripts/make_mesh_scene.py for POV-Ray 3.7: same camera, image, light,
// plane and Phong terms as bumpy.toml, so both renderers trace the same rays. The mesh itself,
// bumpy_mesh.inc (a mesh2 of the generator's bumpy.obj, tens of MB), is written next to this
// file by benchmarks/povray.py. Render at +W1280 +H720 without antialiasing.
#version 3.7;

global_settings {
  assumed_gamma 1.0            // clray works and writes in linear values
  ambient_light rgb <1, 1, 1>  // [render] ambient
  max_trace_level 1            // max_depth 0: primary rays (and shadow rays) only
  adc_bailout 0
}

background { rgb <0.05, 0.05, 0.08> }

// POV-Ray is left-handed; a right vector along -x gives clray's right-handed image. The up
// vector's length (1) spans the image height, so this direction length is vfov = 40 degrees.
camera {
  perspective
  location <0, 2.2, 5>
  sky y
  up y
  right -x * image_width / image_height
  direction z * 0.5 / tan(radians(40 / 2))
  look_at <0, 0.8, 0>
}

light_source { <-4, 6, 5> color rgb <1, 1, 1> }

// clray's solid checker samples a quarter cell below the surface (0.125 for size 0.5), so that
// cells are decided away from the y = 0 boundary; the translate does the same here.
plane {
  y, 0
  texture {
    pigment { checker rgb <0.8, 0.8, 0.8> rgb <0.3, 0.3, 0.3> scale 0.5 translate 0.125 * y }
    finish { ambient 0.1 diffuse 1 }
  }
}

#include "bumpy_mesh.inc"

object {
  Bumpy_Mesh
  texture {
    pigment { rgb <0.85, 0.45, 0.25> }
    finish { ambient 0.1 diffuse 0.8 phong 0.3 phong_size 40 }
  }
}
