// scenes/spheres.toml for POV-Ray 3.7, written so both renderers trace the same rays: same
// camera, image, lights, spheres and Phong terms. benchmarks/README.md ("POV-Ray comparison")
// explains the mapping. Render at +W1280 +H720 without antialiasing.
#version 3.7;

global_settings {
  assumed_gamma 1.0            // clray works and writes in linear values
  ambient_light rgb <1, 1, 1>  // [render] ambient
  max_trace_level 5            // POV-Ray counts the primary ray: max_depth 4 + 1
  adc_bailout 0                // clray never cuts a path for its low weight
}

background { rgb <0.05, 0.07, 0.12> }

// POV-Ray is left-handed; a right vector along -x gives clray's right-handed image. The up
// vector's length (1) spans the image height, so this direction length is vfov = 42 degrees.
camera {
  perspective
  location <0, 6.5, 13>
  sky y
  up y
  right -x * image_width / image_height
  direction z * 0.5 / tan(radians(42 / 2))
  look_at <0, 0.3, 0>
}

light_source { <-6, 10, 6> color rgb <0.7, 0.7, 0.7> }
light_source { <7, 8, 3> color rgb <0.45, 0.45, 0.5> }

// clray's Phong material: phong (not Blinn's specular) is max(r.v, 0)^shininess times the light
// colour, as clray's specular term; reflection is a constant weight, no fresnel or metallic.
#macro Clray(Colour, Ambient, Diffuse, Specular, Shininess, Reflect)
  texture {
    pigment { rgb Colour }
    finish {
      ambient Ambient
      diffuse Diffuse
      phong Specular
      phong_size Shininess
      reflection { Reflect }
    }
  }
#end

plane { y, 0 Clray(<0.75, 0.75, 0.75>, 0.1, 0.7, 0.2, 16, 0.35) }

#declare Red = Clray(<0.9, 0.15, 0.1>, 0.1, 0.7, 0.6, 64, 0.3)
#declare Green = Clray(<0.15, 0.8, 0.25>, 0.1, 0.7, 0.6, 64, 0.3)
#declare Blue = Clray(<0.15, 0.3, 0.9>, 0.1, 0.7, 0.6, 64, 0.3)
#declare Gold = Clray(<0.95, 0.75, 0.2>, 0.1, 0.6, 0.8, 128, 0.45)
#declare Materials = array[4] { Red, Green, Blue, Gold }

// The 8 x 8 grid: rows from z = -7 towards the camera, the colours shifting one per row.
#for (Row, 0, 7)
  #for (Col, 0, 7)
    sphere {
      <-5.25 + 1.5 * Col, 0.6, -7 + 1.5 * Row>, 0.6
      texture { Materials[mod(Row + Col, 4)] }
    }
  #end
#end
